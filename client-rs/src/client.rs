//! Connecting, sessions, and the step stream.

use std::borrow::Cow;
use std::ops::Range;

use tokio::sync::{mpsc, oneshot};
use tokio_stream::wrappers::ReceiverStream;
use tonic::metadata::MetadataValue;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};
use tonic::{Request, Streaming};
use unigait_proto::v1::{self, simulator_client::SimulatorClient};
use unigait_proto::{TensorView, f32_tensor, u8_tensor};

use crate::error::ClientError;

/// Largest message the client accepts or sends: matches the server's default limit.
pub const MAX_MESSAGE_BYTES: usize = 256 << 20;

/// Refuse to send a bearer token without TLS to a host beyond loopback (`localhost` or a
/// loopback IP), where anyone on the path could read it (the Python client refuses the same).
fn refuse_token_in_clear(addr: &str, uri: &tonic::codegen::http::Uri) -> Result<(), ClientError> {
    let host = uri.host().unwrap_or_default();
    let ip = host.trim_start_matches('[').trim_end_matches(']');
    let loopback = host.eq_ignore_ascii_case("localhost")
        || ip
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback());
    if loopback {
        return Ok(());
    }
    Err(ClientError::Address(format!(
        "{addr}: a bearer token would travel in clear text beyond loopback; connect over TLS \
         (give the server's CA certificate, --tls-ca) or leave the token out"
    )))
}

/// A connection to one server.
#[derive(Clone)]
pub struct Client {
    inner: SimulatorClient<Channel>,
    token: Option<MetadataValue<tonic::metadata::Ascii>>,
    addr: String,
}

impl Client {
    /// Connect to `addr` (e.g. `127.0.0.1:50051` or `http://host:port`).
    pub async fn connect(addr: &str) -> Result<Self, ClientError> {
        Self::connect_with_token(addr, None).await
    }

    /// Connect, sending `token` as a bearer token with every call.
    pub async fn connect_with_token(addr: &str, token: Option<&str>) -> Result<Self, ClientError> {
        Self::connect_with(addr, token, None).await
    }

    /// Connect over TLS when `tls` holds (the server's CA certificate in PEM, the server's
    /// name), sending `token` as a bearer token with every call.
    pub async fn connect_with(
        addr: &str,
        token: Option<&str>,
        tls: Option<(&[u8], &str)>,
    ) -> Result<Self, ClientError> {
        let scheme = if tls.is_some() { "https" } else { "http" };
        let uri = if addr.contains("://") {
            addr.to_string()
        } else {
            format!("{scheme}://{addr}")
        };
        if tls.is_none() && uri.starts_with("https://") {
            return Err(ClientError::Address(format!(
                "{addr}: an https address needs the server's CA certificate (--tls-ca)"
            )));
        }
        let endpoint = Endpoint::from_shared(uri).map_err(|_| ClientError::Address(addr.into()))?;
        if token.is_some() && tls.is_none() {
            refuse_token_in_clear(addr, endpoint.uri())?;
        }
        let mut endpoint = endpoint
            .http2_keep_alive_interval(std::time::Duration::from_secs(30))
            .keep_alive_timeout(std::time::Duration::from_secs(20))
            .keep_alive_while_idle(true)
            .tcp_nodelay(true);
        if let Some((ca, domain)) = tls {
            let config = ClientTlsConfig::new()
                .ca_certificate(Certificate::from_pem(ca))
                .domain_name(domain);
            endpoint = endpoint
                .tls_config(config)
                .map_err(|source| ClientError::Connect {
                    addr: addr.into(),
                    source,
                })?;
        }
        let channel = endpoint
            .connect()
            .await
            .map_err(|source| ClientError::Connect {
                addr: addr.into(),
                source,
            })?;
        let inner = SimulatorClient::new(channel)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        let token = match token {
            Some(t) => {
                let mut value: MetadataValue<tonic::metadata::Ascii> =
                    format!("Bearer {t}").parse().map_err(|_| {
                        ClientError::Address("the token is not valid header text".into())
                    })?;
                // Kept out of debug output and HPACK tables.
                value.set_sensitive(true);
                Some(value)
            }
            None => None,
        };
        Ok(Self {
            inner,
            token,
            addr: addr.into(),
        })
    }

    /// The address this client talks to.
    pub fn addr(&self) -> &str {
        &self.addr
    }

    fn request<T>(&self, message: T) -> Request<T> {
        let mut r = Request::new(message);
        if let Some(t) = &self.token {
            r.metadata_mut().insert("authorization", t.clone());
        }
        r
    }

    /// The server's version and limits.
    pub async fn server_info(&mut self) -> Result<v1::ServerInfo, ClientError> {
        let r = self.request(v1::GetServerInfoRequest {});
        Ok(self.inner.get_server_info(r).await?.into_inner())
    }

    /// Create a session.
    pub async fn create_session(
        &mut self,
        config: v1::SessionConfig,
    ) -> Result<Session, ClientError> {
        let r = self.request(v1::CreateSessionRequest {
            config: Some(config),
        });
        let reply = self.inner.create_session(r).await?.into_inner();
        let spec = reply.spec.ok_or(ClientError::Missing("spec"))?;
        let initial = reply.initial.ok_or(ClientError::Missing("initial"))?;
        Ok(Session {
            client: self.clone(),
            id: reply.session_id,
            spec: Spec(spec),
            initial: Step(initial),
        })
    }

    /// Roll out an ONNX policy on the server over a scenario.
    pub async fn evaluate(
        &mut self,
        message: v1::EvaluateRequest,
    ) -> Result<v1::EvaluateResponse, ClientError> {
        let r = self.request(message);
        Ok(self.inner.evaluate(r).await?.into_inner())
    }

    /// Raw access to the generated client (for tests of odd requests).
    pub fn raw(&mut self) -> &mut SimulatorClient<Channel> {
        &mut self.inner
    }
}

/// A session's spec with lookups by name.
#[derive(Clone, Debug, PartialEq)]
pub struct Spec(pub v1::Spec);

impl Spec {
    /// Number of envs.
    pub fn num_envs(&self) -> usize {
        self.0.num_envs as usize
    }

    /// The spec of tensor `name`.
    pub fn tensor(&self, name: &str) -> Option<&v1::TensorSpec> {
        self.0.tensors.iter().find(|t| t.name == name)
    }

    /// Values per env of tensor `name` (1 for scalars).
    pub fn row_size(&self, name: &str) -> Option<usize> {
        self.tensor(name)
            .map(|t| t.shape.iter().map(|&d| d as usize).product())
    }

    /// The range of field `field` within a row of tensor `tensor` (e.g. "obs", "clock").
    pub fn slice(&self, tensor: &str, field: &str) -> Option<Range<usize>> {
        let f = self
            .tensor(tensor)?
            .fields
            .iter()
            .find(|f| f.name == field)?;
        Some(f.offset as usize..(f.offset + f.size) as usize)
    }
}

/// One step's reply, with typed, checked, zero-copy (when aligned) views.
#[derive(Clone, Debug, PartialEq)]
pub struct Step(pub v1::StepResult);

macro_rules! f32_view {
    ($name:ident) => {
        #[doc = concat!("The `", stringify!($name), "` values.")]
        pub fn $name(&self) -> Result<Cow<'_, [f32]>, ClientError> {
            Ok(self
                .0
                .$name
                .as_ref()
                .ok_or(ClientError::Missing(stringify!($name)))?
                .f32_values(stringify!($name))?)
        }
    };
}

macro_rules! u8_view {
    ($name:ident) => {
        #[doc = concat!("The `", stringify!($name), "` flags.")]
        pub fn $name(&self) -> Result<&[u8], ClientError> {
            Ok(self
                .0
                .$name
                .as_ref()
                .ok_or(ClientError::Missing(stringify!($name)))?
                .u8_values(stringify!($name))?)
        }
    };
}

impl Step {
    f32_view!(obs);
    f32_view!(labels);
    f32_view!(privileged);
    f32_view!(reward);
    f32_view!(reward_terms);
    f32_view!(final_obs);
    f32_view!(final_labels);
    f32_view!(final_privileged);
    u8_view!(terminated);
    u8_view!(truncated);
    u8_view!(mode);

    /// Ids of the envs that ended this step.
    pub fn final_env_ids(&self) -> Result<Cow<'_, [u32]>, ClientError> {
        Ok(self
            .0
            .final_env_ids
            .as_ref()
            .ok_or(ClientError::Missing("final_env_ids"))?
            .u32_values("final_env_ids")?)
    }
}

/// A session on a server.
pub struct Session {
    client: Client,
    /// The session id.
    pub id: String,
    /// Its spec.
    pub spec: Spec,
    /// The first observations.
    pub initial: Step,
}

impl Session {
    fn actions(&self, actions: &[f32]) -> v1::Tensor {
        let n = self.spec.num_envs();
        f32_tensor(actions, &[n, actions.len().checked_div(n).unwrap_or(0)])
    }

    /// One step by a unary call.
    pub async fn step(&mut self, actions: &[f32]) -> Result<Step, ClientError> {
        let req = v1::StepRequest {
            session_id: self.id.clone(),
            actions: Some(self.actions(actions)),
            reward_terms: false,
            draw_envs: Vec::new(),
        };
        let r = self.client.request(req);
        Ok(Step(self.client.inner.step(r).await?.into_inner()))
    }

    /// Reset every env, or those where `mask` is non-zero.
    pub async fn reset(&mut self, mask: Option<&[u8]>) -> Result<Step, ClientError> {
        let req = v1::ResetRequest {
            session_id: self.id.clone(),
            mask: mask.map(|m| u8_tensor(m, &[m.len()])),
        };
        let r = self.client.request(req);
        Ok(Step(self.client.inner.reset(r).await?.into_inner()))
    }

    /// Open the session's bidirectional step stream.
    pub async fn stream(&mut self) -> Result<StepStream, ClientError> {
        StepStream::open(&mut self.client, &self.id, self.spec.num_envs()).await
    }

    /// Close the session.
    pub async fn close(mut self) -> Result<(), ClientError> {
        let r = self.client.request(v1::CloseSessionRequest {
            session_id: self.id.clone(),
        });
        self.client.inner.close_session(r).await?;
        Ok(())
    }
}

/// The call's outcome once the server has answered it: its response stream or its status.
type Opening = oneshot::Receiver<Result<Streaming<v1::StepResult>, tonic::Status>>;

/// A bidirectional stream of steps: send actions, receive the step's results, in order.
pub struct StepStream {
    tx: mpsc::Sender<v1::StepRequest>,
    rx: Option<Streaming<v1::StepResult>>,
    opening: Option<Opening>,
    session_id: String,
    num_envs: usize,
    first: bool,
}

impl StepStream {
    async fn open(
        client: &mut Client,
        session_id: &str,
        num_envs: usize,
    ) -> Result<Self, ClientError> {
        let (tx, requests) = mpsc::channel(2);
        let r = client.request(ReceiverStream::new(requests));
        let mut inner = client.inner.clone();
        let (answered, opening) = oneshot::channel();
        // gRPC core servers (Python's among them) send the response headers with the first
        // response, which needs the first request: awaiting them before sending one deadlocks.
        // The call runs on its own task and the first receive collects it.
        tokio::spawn(async move {
            let outcome = inner.step_stream(r).await.map(tonic::Response::into_inner);
            // The stream may have been dropped unused: nobody to tell.
            let _ = answered.send(outcome);
        });
        Ok(StepStream {
            tx,
            rx: None,
            opening: Some(opening),
            session_id: session_id.into(),
            num_envs,
            first: true,
        })
    }

    /// The response stream, waiting for the server's answer to the call the first time.
    async fn responses(&mut self) -> Result<&mut Streaming<v1::StepResult>, ClientError> {
        if let Some(opening) = self.opening.take() {
            let outcome = opening.await.map_err(|_| ClientError::StreamClosed)?;
            self.rx = Some(outcome?);
        }
        self.rx.as_mut().ok_or(ClientError::StreamClosed)
    }

    /// Send one batch of actions ([num_envs, 12]) and wait for its results.
    pub async fn step(&mut self, actions: &[f32]) -> Result<Step, ClientError> {
        self.send(actions, false).await?;
        self.receive().await
    }

    /// Send actions without waiting (pair each `send` with one `receive`).
    pub async fn send(&mut self, actions: &[f32], reward_terms: bool) -> Result<(), ClientError> {
        // Only the first request needs to name the session.
        let session_id = if self.first {
            self.session_id.clone()
        } else {
            String::new()
        };
        self.first = false;
        let per_env = actions.len().checked_div(self.num_envs).unwrap_or(0);
        let req = v1::StepRequest {
            session_id,
            actions: Some(f32_tensor(actions, &[self.num_envs, per_env])),
            reward_terms,
            draw_envs: Vec::new(),
        };
        if self.tx.send(req).await.is_err() {
            // The call ended before taking the request: its status says why.
            if self.rx.is_none() {
                self.responses().await?;
            }
            return Err(ClientError::StreamClosed);
        }
        Ok(())
    }

    /// Receive the results of the oldest unanswered `send`.
    pub async fn receive(&mut self) -> Result<Step, ClientError> {
        match self.responses().await?.message().await? {
            Some(result) => Ok(Step(result)),
            None => Err(ClientError::StreamClosed),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(addr: &str) -> Result<(), ClientError> {
        let uri = if addr.contains("://") {
            addr.to_string()
        } else {
            format!("http://{addr}")
        };
        let endpoint = Endpoint::from_shared(uri).expect("uri");
        refuse_token_in_clear(addr, endpoint.uri())
    }

    #[test]
    fn issue_36_a_token_in_clear_text_beyond_loopback_is_refused() {
        for addr in [
            "10.1.2.3:50051",
            "http://example.org:50051",
            "[2001:db8::1]:50051",
        ] {
            match check(addr) {
                Err(ClientError::Address(m)) => assert!(m.contains("clear text"), "{m}"),
                other => panic!("{addr}: {other:?}"),
            }
        }
        for addr in [
            "127.0.0.1:50051",
            "localhost:50051",
            "[::1]:50051",
            "http://LOCALHOST:1",
        ] {
            check(addr).unwrap_or_else(|e| panic!("{addr}: {e}"));
        }
    }

    #[tokio::test]
    async fn issue_36_connect_refuses_the_token_before_connecting() {
        // Port 9 of a documentation address: nothing is dialled, the check comes first.
        let connect = Client::connect_with("192.0.2.1:9", Some("0123456789abcdef"), None);
        let refused = tokio::time::timeout(std::time::Duration::from_secs(5), connect)
            .await
            .expect("refused at once, without dialling");
        assert!(
            matches!(&refused, Err(ClientError::Address(m)) if m.contains("clear text")),
            "{:?}",
            refused.err()
        );
    }
}

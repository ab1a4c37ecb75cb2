//! The viewer layout sent with every recording (a rerun blueprint).
//!
//! Without one, rerun's viewer tiles every entity tree into an equal grid (eleven tiles, the 3D
//! view one of them, plots picked by heuristics). This layout shows what a rollout is about: a
//! large 3D view whose camera follows the robot's base, and beside it the velocity command
//! against the measured velocity, pitch and base height against the upright threshold, a gait
//! diagram with the task mode on top, and the reward of the active mode. Every other series stays
//! in the store (the streams panel lists it) without a view of its own.
//!
//! The layout is described by plain data ([`Layout`], [`Node`], [`ViewSpec`]) so that tests can
//! check that every entity it names exists in the recording, and turned into rerun's blueprint
//! archetypes by [`Layout::send`]. rerun 0.36's Rust blueprint builder (`rerun::blueprint`) has
//! no way to set a 3D view's eye (its `EyeControls3D` property), which the follow camera needs,
//! so the archetypes are logged here the way that builder logs them (same entity paths), to a
//! blueprint store sent along with the recording: a file, a memory `.rrd`, a live viewer and a
//! served recording all carry it, and the viewer activates it on load.

use std::collections::BTreeSet;

use rerun::external::re_log_types::{BlueprintActivationCommand, LogMsg};
use rerun::external::re_sdk_types::blueprint::archetypes::{
    ContainerBlueprint, EyeControls3D, PanelBlueprint, TimePanelBlueprint, ViewBlueprint,
    ViewContents, ViewportBlueprint,
};
use rerun::external::re_sdk_types::blueprint::components::{
    ActiveTab, AutoLayout, AutoViews, ColumnShare, ContainerKind, IncludedContent, PanelState,
    QueryExpression, RootContainer, RowShare, ViewClass,
};
use rerun::external::re_sdk_types::components::{Name, Position3D, Vector3D};
use rerun::{RecordingStream, RecordingStreamBuilder};

use crate::error::RecordError;

/// What a view shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewKind {
    /// A 3D scene.
    Spatial3D,
    /// Scalar series over time.
    TimeSeries,
    /// Discrete states as coloured lanes over time (`StateChange`).
    StateTimeline,
    /// Text events.
    TextLog,
}

impl ViewKind {
    /// rerun's view class identifier.
    pub fn class(self) -> &'static str {
        match self {
            ViewKind::Spatial3D => "3D",
            ViewKind::TimeSeries => "TimeSeries",
            ViewKind::StateTimeline => "StateTimeline",
            ViewKind::TextLog => "TextLog",
        }
    }
}

/// Where a 3D view's camera starts and what it follows.
#[derive(Clone, Debug, PartialEq)]
pub struct Eye {
    /// Entity the camera follows (keeps its offset to it as it moves).
    pub tracking: String,
    /// Camera position at the start (m, world).
    pub position: [f32; 3],
    /// Point looked at at the start (m, world).
    pub look_target: [f32; 3],
}

/// One view: a name, a class, an origin and the entities it shows.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewSpec {
    /// Title shown in the viewer.
    pub name: String,
    /// View class.
    pub kind: ViewKind,
    /// Space origin (entity path).
    pub origin: String,
    /// rerun query expressions: `+ /path` (one entity), `+ /path/**` (a subtree), `- ...`
    /// to leave out.
    pub contents: Vec<String>,
    /// For a 3D view: the camera.
    pub eye: Option<Eye>,
}

impl ViewSpec {
    fn new(name: impl Into<String>, kind: ViewKind, origin: &str, contents: Vec<String>) -> Self {
        Self {
            name: name.into(),
            kind,
            origin: origin.into(),
            contents,
            eye: None,
        }
    }
}

/// How a container arranges its children.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arrange {
    /// Left to right.
    Horizontal,
    /// Top to bottom.
    Vertical,
    /// One child at a time, picked by tab.
    Tabs,
}

/// A view or a container of nodes.
#[derive(Clone, Debug, PartialEq)]
pub enum Node {
    /// A view.
    View(ViewSpec),
    /// Children arranged side by side, stacked or as tabs.
    Container {
        /// Arrangement.
        arrange: Arrange,
        /// Relative sizes of the children (horizontal: widths, vertical: heights); empty: equal.
        shares: Vec<f32>,
        /// For tabs: the index of the tab shown first.
        active: usize,
        /// The children.
        children: Vec<Node>,
    },
}

impl Node {
    fn container(arrange: Arrange, shares: Vec<f32>, children: Vec<Node>) -> Self {
        Node::Container {
            arrange,
            shares,
            active: 0,
            children,
        }
    }

    fn collect_views<'a>(&'a self, out: &mut Vec<&'a ViewSpec>) {
        match self {
            Node::View(v) => out.push(v),
            Node::Container { children, .. } => {
                for c in children {
                    c.collect_views(out);
                }
            }
        }
    }
}

/// The whole viewer layout: the views and how they are arranged.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// The root container.
    pub root: Node,
}

/// The recorded envs a layout is built for.
#[derive(Clone, Debug, PartialEq)]
pub struct LayoutInput {
    /// Per recorded env (the followed env first): its label (`env 3`), the entity the camera
    /// follows (its robot's trunk) and the base position at the start.
    pub envs: Vec<LayoutEnv>,
    /// Entity subtrees of the other envs (left out of the followed env's 3D view).
    pub other_roots: Vec<String>,
    /// Reward series of the active mode's terms (`reward/active/...`) and the per-task sums.
    pub reward_series: Vec<String>,
}

/// One recorded env of a [`LayoutInput`].
#[derive(Clone, Debug, PartialEq)]
pub struct LayoutEnv {
    /// Tab title.
    pub label: String,
    /// Query expressions of its 3D view.
    pub contents: Vec<String>,
    /// The entity its camera follows: the trunk shape of its robot's base.
    pub base: String,
    /// Base position at the start (m, world).
    pub base_start: [f32; 3],
}

/// Camera offset from the base at the start: beside a robot walking along +x, slightly behind
/// and above, about 2 m away, so the legs read (a gait is seen from the side), the robot fills
/// the view and the terrain around it shows.
const EYE_OFFSET: [f32; 3] = [-0.6, -1.9, 0.6];

fn plus(path: &str) -> String {
    format!("+ /{path}")
}

fn subtree(path: &str) -> String {
    format!("+ /{path}/**")
}

impl Layout {
    /// The unigait layout for the recorded envs.
    pub fn unigait(input: &LayoutInput) -> Self {
        let scenes: Vec<Node> = input
            .envs
            .iter()
            .map(|e| {
                let mut view = ViewSpec::new(
                    format!("3D: {}", e.label),
                    ViewKind::Spatial3D,
                    "world",
                    e.contents.clone(),
                );
                let b = e.base_start;
                view.eye = Some(Eye {
                    tracking: e.base.clone(),
                    position: [
                        b[0] + EYE_OFFSET[0],
                        b[1] + EYE_OFFSET[1],
                        b[2] + EYE_OFFSET[2],
                    ],
                    look_target: b,
                });
                Node::View(view)
            })
            .collect();
        let scene = Node::Container {
            arrange: Arrange::Tabs,
            shares: Vec::new(),
            active: 0,
            children: scenes,
        };
        let events = Node::View(ViewSpec::new(
            "events: mode switches, falls, head hits, outcome per env",
            ViewKind::TextLog,
            "/",
            vec![subtree("events"), plus("events")],
        ));
        let left = Node::container(Arrange::Vertical, vec![4.0, 1.0], vec![scene, events]);

        let velocity = Node::View(ViewSpec::new(
            "velocity, heading frame: command vs measured",
            ViewKind::TimeSeries,
            "/",
            [
                "command/vx",
                "state/vx",
                "command/vy",
                "state/vy",
                "command/wz",
            ]
            .into_iter()
            .chain(["state/yaw_rate"])
            .map(plus)
            .collect(),
        ));
        let posture = Node::View(ViewSpec::new(
            "pitch (rad) vs upright threshold, base height (m)",
            ViewKind::TimeSeries,
            "/",
            ["state/pitch", "state/upright_pitch", "state/base_height"]
                .into_iter()
                .map(plus)
                .collect(),
        ));
        let gait = Node::View(ViewSpec::new(
            "task mode and gait diagram (stance bars)",
            ViewKind::StateTimeline,
            "/",
            vec![subtree("gait")],
        ));
        let mut reward_contents = vec![plus("reward/total")];
        reward_contents.extend(input.reward_series.iter().map(|p| plus(p)));
        let reward = Node::View(ViewSpec::new(
            "reward: total and the active mode's terms",
            ViewKind::TimeSeries,
            "/",
            reward_contents,
        ));
        let right = Node::container(
            Arrange::Vertical,
            vec![1.0, 0.9, 1.25, 1.1],
            vec![velocity, posture, gait, reward],
        );
        Layout {
            root: Node::container(Arrange::Horizontal, vec![1.45, 1.0], vec![left, right]),
        }
    }

    /// Every view, depth first.
    pub fn views(&self) -> Vec<&ViewSpec> {
        let mut out = Vec::new();
        self.root.collect_views(&mut out);
        out
    }

    /// The entity paths the layout names (without the leading slash): what its views' `+`
    /// queries include (a subtree's root for `/**`) and what their cameras follow.
    pub fn named_entities(&self) -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        for v in self.views() {
            for q in &v.contents {
                if let Some(p) = q.strip_prefix("+ /") {
                    let p = p.strip_suffix("/**").unwrap_or(p);
                    out.insert(p.to_string());
                }
            }
            if let Some(eye) = &v.eye {
                out.insert(eye.tracking.clone());
            }
        }
        out
    }

    /// The blueprint as rerun log messages of a fresh blueprint store of `application_id`,
    /// and the store's activation command.
    pub fn to_messages(
        &self,
        application_id: &'static str,
    ) -> Result<(Vec<LogMsg>, BlueprintActivationCommand), RecordError> {
        let (bp, storage) = RecordingStreamBuilder::new(application_id)
            .blueprint()
            .memory()
            .map_err(bp_err)?;
        // The viewer reads blueprint data on this timeline.
        bp.set_time_sequence("blueprint", 0);
        let root = log_node(&bp, &self.root)?;
        bp.log(
            "viewport",
            &ViewportBlueprint::new()
                .with_root_container(RootContainer(root.into()))
                .with_auto_layout(AutoLayout(false.into()))
                .with_auto_views(AutoViews(false.into())),
        )
        .map_err(bp_err)?;
        // Room for the views: the blueprint tree and the selection start folded away (a click
        // opens them); the time panel stays for scrubbing.
        for panel in ["blueprint_panel", "selection_panel"] {
            bp.log(
                panel,
                &PanelBlueprint::new().with_state(PanelState::Collapsed),
            )
            .map_err(bp_err)?;
        }
        bp.log(
            "time_panel",
            &TimePanelBlueprint::new()
                .with_state(PanelState::Collapsed)
                .with_timeline("sim_time"),
        )
        .map_err(bp_err)?;
        let msgs = storage.take();
        let blueprint_id = msgs
            .first()
            .map(|m| m.store_id().clone())
            .ok_or_else(|| RecordError::Finish("the blueprint store is empty".into()))?;
        let activate = BlueprintActivationCommand {
            blueprint_id,
            make_active: true,
            make_default: true,
        };
        Ok((msgs, activate))
    }

    /// Send the blueprint along with `rec`'s recording (same application id), to be
    /// activated by the viewer as soon as it has it all.
    pub fn send(
        &self,
        rec: &RecordingStream,
        application_id: &'static str,
    ) -> Result<(), RecordError> {
        let (msgs, activate) = self.to_messages(application_id)?;
        rec.send_blueprint(msgs, activate);
        Ok(())
    }
}

fn bp_err(e: impl std::fmt::Display) -> RecordError {
    RecordError::Finish(format!("cannot build the viewer blueprint: {e}"))
}

/// Log a node and its children; returns its id (blueprint paths are `view/<id>` and
/// `container/<id>`, as rerun's own builder writes them).
fn log_node(bp: &RecordingStream, node: &Node) -> Result<uuid::Uuid, RecordError> {
    let id = uuid::Uuid::new_v4();
    match node {
        Node::View(v) => {
            let path = format!("view/{id}");
            bp.log(
                format!("{path}/ViewContents"),
                &ViewContents::new(v.contents.iter().map(|q| QueryExpression(q.clone().into()))),
            )
            .map_err(bp_err)?;
            bp.log(
                path.as_str(),
                &ViewBlueprint::new(ViewClass(v.kind.class().into()))
                    .with_display_name(Name(v.name.clone().into()))
                    .with_space_origin(v.origin.as_str()),
            )
            .map_err(bp_err)?;
            if let Some(eye) = &v.eye {
                bp.log(
                    format!("{path}/EyeControls3D"),
                    &EyeControls3D::new()
                        .with_position(Position3D::from(eye.position))
                        .with_look_target(Position3D::from(eye.look_target))
                        .with_eye_up(Vector3D::from([0.0, 0.0, 1.0]))
                        .with_tracking_entity(eye.tracking.as_str()),
                )
                .map_err(bp_err)?;
            }
        }
        Node::Container {
            arrange,
            shares,
            active,
            children,
        } => {
            let mut paths = Vec::with_capacity(children.len());
            for c in children {
                let child = log_node(bp, c)?;
                paths.push(match c {
                    Node::View(_) => format!("view/{child}"),
                    Node::Container { .. } => format!("container/{child}"),
                });
            }
            let kind = match arrange {
                Arrange::Horizontal => ContainerKind::Horizontal,
                Arrange::Vertical => ContainerKind::Vertical,
                Arrange::Tabs => ContainerKind::Tabs,
            };
            let mut arch = ContainerBlueprint::new(kind).with_contents(
                paths
                    .iter()
                    .map(|p| IncludedContent(p.as_str().into()))
                    .collect::<Vec<_>>(),
            );
            if !shares.is_empty() {
                match arrange {
                    Arrange::Horizontal => {
                        arch = arch.with_col_shares(
                            shares
                                .iter()
                                .map(|&s| ColumnShare(s.into()))
                                .collect::<Vec<_>>(),
                        );
                    }
                    Arrange::Vertical => {
                        arch = arch.with_row_shares(
                            shares
                                .iter()
                                .map(|&s| RowShare(s.into()))
                                .collect::<Vec<_>>(),
                        );
                    }
                    Arrange::Tabs => {}
                }
            }
            if *arrange == Arrange::Tabs
                && let Some(tab) = paths.get(*active)
            {
                arch = arch.with_active_tab(ActiveTab(tab.as_str().into()));
            }
            bp.log(format!("container/{id}"), &arch).map_err(bp_err)?;
        }
    }
    Ok(id)
}

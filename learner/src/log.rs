//! `progress.csv`: one row of scalars per iteration, the Python learner's columns and number
//! format (`%.6g`, NaN as an empty cell), so the same plotting and comparison tools read both.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::Result;
use crate::learner::Scalars;

/// `v` as Python's `f"{v:.6g}"` (NaN: empty).
pub fn fmt_g(v: f64) -> String {
    if v.is_nan() {
        return String::new();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".into() } else { "-inf".into() };
    }
    if v == 0.0 {
        return if v.is_sign_negative() {
            "-0".into()
        } else {
            "0".into()
        };
    }
    // The exponent after rounding to 6 significant digits decides the style.
    let sci = format!("{v:.5e}");
    let (mantissa, exp) = sci.split_once('e').expect("{:e} has an exponent");
    let exp: i32 = exp.parse().expect("an integer exponent");
    if (-4..6).contains(&exp) {
        let decimals = (5 - exp).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let m = if mantissa.contains('.') {
            mantissa.trim_end_matches('0').trim_end_matches('.')
        } else {
            mantissa
        };
        let sign = if exp < 0 { '-' } else { '+' };
        format!("{m}e{sign}{:02}", exp.abs())
    }
}

/// Writes `progress.csv` in a folder.
#[derive(Debug)]
pub struct ProgressLog {
    path: PathBuf,
    columns: Option<Vec<String>>,
}

impl ProgressLog {
    /// The log of `dir` (a resumed run keeps its rows).
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join("progress.csv");
        let columns = match std::fs::read_to_string(&path) {
            Ok(text) => text
                .lines()
                .next()
                .map(|h| h.split(',').map(String::from).collect()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => return Err(e.into()),
        };
        Ok(Self { path, columns })
    }

    /// Its file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Forget the rows past `iteration` (a run resumed from an older checkpoint than its last
    /// row trains them again).
    pub fn drop_after(&mut self, iteration: u64) -> Result<()> {
        let Some(columns) = &self.columns else {
            return Ok(());
        };
        let Some(col) = columns.iter().position(|c| c == "iteration") else {
            return Ok(());
        };
        let text = std::fs::read_to_string(&self.path)?;
        let mut lines = text.lines();
        let header = lines.next().unwrap_or_default();
        let kept: Vec<&str> = lines
            .filter(|l| {
                l.split(',')
                    .nth(col)
                    .and_then(|v| v.parse::<f64>().ok())
                    .is_none_or(|it| it <= iteration as f64)
            })
            .collect();
        let mut out = String::from(header);
        out.push('\n');
        for l in kept {
            out.push_str(l);
            out.push('\n');
        }
        let tmp = self.path.with_extension("csv.tmp");
        std::fs::write(&tmp, out)?;
        std::fs::rename(&tmp, &self.path)?;
        Ok(())
    }

    /// Append one row (the first row's names are the header; later names not in it are
    /// dropped, missing ones left empty).
    pub fn log(&mut self, scalars: &Scalars) -> Result<()> {
        let columns = match &self.columns {
            Some(c) => c.clone(),
            None => {
                let c: Vec<String> = scalars.iter().map(|(k, _)| k.clone()).collect();
                std::fs::write(&self.path, format!("{}\n", c.join(",")))?;
                self.columns = Some(c.clone());
                c
            }
        };
        let row: Vec<String> = columns
            .iter()
            .map(|c| {
                scalars
                    .iter()
                    .find(|(k, _)| k == c)
                    .map_or(String::new(), |(_, v)| fmt_g(*v))
            })
            .collect();
        let mut f = std::fs::OpenOptions::new().append(true).open(&self.path)?;
        writeln!(f, "{}", row.join(","))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Python's `f"{v:.6g}"` for each.
    #[test]
    fn six_significant_digits_like_python() {
        for (v, s) in [
            (26443800.0, "2.64438e+07"),
            (3956.0123, "3956.01"),
            (0.583_735_4, "0.583735"),
            (-0.000_123_457, "-0.000123457"),
            (-8.888_89e-7, "-8.88889e-07"),
            (1076.0, "1076"),
            (1.45, "1.45"),
            (0.0, "0"),
            (100000.0, "100000"),
            (1_000_000.0, "1e+06"),
            (999_999.5, "1e+06"),
            (0.0001, "0.0001"),
            (2.25e-05, "2.25e-05"),
            (f64::NAN, ""),
        ] {
            assert_eq!(fmt_g(v), s, "{v}");
        }
    }

    #[test]
    fn rows_follow_the_header_and_resume_drops_later_rows() {
        let dir = std::env::temp_dir().join(format!("unigait-log-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut log = ProgressLog::open(&dir).unwrap();
        for it in 1..=3 {
            log.log(&vec![
                ("iteration".into(), f64::from(it)),
                ("x".into(), if it == 2 { f64::NAN } else { 0.5 }),
            ])
            .unwrap();
        }
        let mut log = ProgressLog::open(&dir).unwrap();
        log.drop_after(2).unwrap();
        log.log(&vec![
            ("x".into(), 1.0),
            ("iteration".into(), 3.0),
            ("y".into(), 2.0),
        ])
        .unwrap();
        let text = std::fs::read_to_string(log.path()).unwrap();
        assert_eq!(text, "iteration,x\n1,0.5\n2,\n3,1\n");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

//! The OpenJD job bundle of a shooting day (DESIGN.md §4 "Farm job bundle"): a template in
//! Open Job Description's `jobtemplate-2023-09` schema and its `parameter_values.yaml`
//! (the job bundle layout AWS Deadline Cloud's `deadline bundle submit` reads).
//!
//! Per take, two steps:
//! - `Chunks <take>`: one task per chunk of frames. Its task parameters `Start` and `End`
//!   are associated (`combination: "(Start, End)"`), so a task runs
//!   `replay SESSION --frames Start..End --warm-up W --relabel-every C --relabel-lead W
//!   --out OUT/chunks/<take>/<Start>` (C the chunk size: labeling restarts where every
//!   chunk's warm-up starts, so the merged take equals one replay with the same options).
//! - `Merge <take>` (depends on its chunks): `farm merge OUT/chunks/<take> --out OUT/<take>`.
//!
//! Then one `Report` step (depends on every merge) writes the dailies report into
//! `OUT/report`. Every path is a `PATH` job parameter (the helmcap executable, each
//! session, the output folder, and any file a replay option names), so a farm's path
//! mapping can move them between operating systems and mount points; their values are in
//! `parameter_values.yaml`, the template itself holds no absolute path.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::param_error::ParamError;

/// One chunk of a take: frames `start..end` (end excluded) are written, frames
/// `warm_up_from..start` run first to warm the stages up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Chunk {
    /// First frame written.
    pub start: usize,
    /// One past the last frame written.
    pub end: usize,
    /// First frame run (warm-up), at most `start`.
    pub warm_up_from: usize,
}

/// Splits the frames `first..=last` into chunks of `chunk` frames (the last one shorter),
/// each warmed up by up to `overlap` frames before it (never before `first`).
///
/// # Errors
/// A chunk size of 0, or `last < first`.
pub fn chunk_ranges(
    first: usize,
    last: usize,
    chunk: usize,
    overlap: usize,
) -> Result<Vec<Chunk>, String> {
    if chunk == 0 {
        return Err("the chunk size must be at least one frame".into());
    }
    if last < first {
        return Err(format!("no frames: {first}..={last}"));
    }
    Ok((first..=last)
        .step_by(chunk)
        .map(|start| Chunk {
            start,
            end: start.saturating_add(chunk).min(last + 1),
            warm_up_from: start.saturating_sub(overlap).max(first),
        })
        .collect())
}

/// A take of the day: its name (the session folder's name) and session folder.
#[derive(Debug, Clone, PartialEq)]
pub struct JobTake {
    /// Name (unique in the job; names the take's output folder and steps).
    pub name: String,
    /// Session folder (absolute).
    pub session: PathBuf,
    /// The chunks.
    pub chunks: Vec<Chunk>,
}

/// A replay option of every chunk: a flag, a value, or a file (which becomes a PATH job
/// parameter).
#[derive(Debug, Clone, PartialEq)]
pub enum ReplayOption {
    /// `--flag`.
    Flag(String),
    /// `--name value`.
    Value(String, String),
    /// `--name FILE`: the file is the job parameter `param` (absolute path).
    File {
        /// The option (`--calib`).
        option: String,
        /// The job parameter's name (`Calib`).
        param: String,
        /// The file.
        path: PathBuf,
    },
}

/// Everything a job bundle is made of.
#[derive(Debug, Clone, PartialEq)]
pub struct JobSpec {
    /// The job's name.
    pub name: String,
    /// The helmcap executable the workers run (absolute; remappable).
    pub helmcap: PathBuf,
    /// Where the chunks, merged takes and report go (absolute; remappable).
    pub out: PathBuf,
    /// The takes.
    pub takes: Vec<JobTake>,
    /// Warm-up frames before each chunk (an INT job parameter, `WarmUpFrames`).
    pub overlap: usize,
    /// Frames per chunk (the last chunk of a take may be shorter): every chunk passes it
    /// to `replay --relabel-every`, so labeling restarts where each chunk's warm-up starts
    /// in a single pass too.
    pub chunk: usize,
    /// Replay options of every chunk.
    pub replay_options: Vec<ReplayOption>,
}

/// The longest step name OpenJD allows.
const MAX_STEP_NAME: usize = 64;

/// A YAML single-quoted string.
fn q(s: &str) -> String {
    format!("'{}'", s.replace('\'', "''"))
}

/// True when `name` can be a job parameter's name (`[A-Za-z_][A-Za-z0-9_]*`).
fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && name.len() <= 64
}

impl JobSpec {
    /// Checks names: unique take names that fit OpenJD's step names, identifiers for the
    /// file options' parameters, at least one chunk per take.
    ///
    /// # Errors
    /// [`ParamError`] naming what is wrong (`take name "a/b" cannot name a folder`).
    pub fn validate(&self) -> Result<(), ParamError> {
        if self.takes.is_empty() {
            return Err(ParamError::new("takes", "must name at least one session"));
        }
        if self.chunk == 0 {
            return Err(ParamError::new("chunk", "must be at least one frame"));
        }
        for (i, t) in self.takes.iter().enumerate() {
            let name_err = |requirement: String| ParamError::new("take name", requirement);
            if t.name.is_empty()
                || t.name
                    .chars()
                    .any(|c| c.is_control() || c == '/' || c == '\\')
            {
                return Err(name_err(format!("{:?} cannot name a folder", t.name)));
            }
            if format!("Chunks {}", t.name).len() > MAX_STEP_NAME {
                return Err(name_err(format!(
                    "{:?} is longer than OpenJD's step names allow ({} characters with \
                     \"Chunks \")",
                    t.name, MAX_STEP_NAME
                )));
            }
            if let Some(other) = self.takes[..i].iter().find(|o| o.name == t.name) {
                return Err(name_err(format!(
                    "{:?} is used by two takes ({} and {}): their outputs would collide",
                    t.name,
                    other.session.display(),
                    t.session.display()
                )));
            }
            if t.chunks.is_empty() {
                return Err(ParamError::new("take", format!("{} has no frames", t.name)));
            }
        }
        for o in &self.replay_options {
            if let ReplayOption::File { param, .. } = o
                && !is_identifier(param)
            {
                return Err(ParamError::new(
                    "parameter name",
                    format!("{param:?} cannot name a job parameter"),
                ));
            }
        }
        Ok(())
    }

    /// The template (`template.yaml`).
    pub fn template(&self) -> String {
        let mut y = String::new();
        let _ = writeln!(y, "specificationVersion: 'jobtemplate-2023-09'");
        let _ = writeln!(y, "name: {}", q(&self.name));
        let frames: usize = self
            .takes
            .iter()
            .flat_map(|t| &t.chunks)
            .map(|c| c.end - c.start)
            .sum();
        let _ = writeln!(
            y,
            "description: {}",
            q(&format!(
                "helmcap dailies: {} takes, {frames} frames, chunked replays merged per take, \
                 then the dailies report",
                self.takes.len()
            ))
        );
        y.push_str("parameterDefinitions:\n");
        param_path(
            &mut y,
            "HelmcapExe",
            "FILE",
            "NONE",
            "The helmcap executable on the workers.",
        );
        param_path(
            &mut y,
            "OutDir",
            "DIRECTORY",
            "OUT",
            "Output folder: chunks/<take>/<start>/, one merged folder per take, report/.",
        );
        for (i, t) in self.takes.iter().enumerate() {
            param_path(
                &mut y,
                &session_param(i),
                "DIRECTORY",
                "IN",
                &format!("Session folder of take {}.", t.name),
            );
        }
        for o in &self.replay_options {
            if let ReplayOption::File { option, param, .. } = o {
                param_path(
                    &mut y,
                    param,
                    "FILE",
                    "IN",
                    &format!("The file of replay {option}."),
                );
            }
        }
        let _ = writeln!(
            y,
            "- name: WarmUpFrames\n  type: INT\n  minValue: 0\n  default: {}\n  description: {}",
            self.overlap,
            q("Frames each chunk runs before its range to warm up tracking and smoothing.")
        );
        y.push_str("steps:\n");
        for (i, t) in self.takes.iter().enumerate() {
            let starts: Vec<String> = t.chunks.iter().map(|c| c.start.to_string()).collect();
            let ends: Vec<String> = t.chunks.iter().map(|c| c.end.to_string()).collect();
            let chunk_dir = format!("{{{{Param.OutDir}}}}/chunks/{}", t.name);
            let mut args = vec![
                q("replay"),
                q(&format!("{{{{Param.{}}}}}", session_param(i))),
                q("--frames"),
                q("{{Task.Param.Start}}..{{Task.Param.End}}"),
                q("--warm-up"),
                q("{{Param.WarmUpFrames}}"),
                q("--relabel-every"),
                q(&self.chunk.to_string()),
                q("--relabel-lead"),
                q("{{Param.WarmUpFrames}}"),
                q("--out"),
                q(&format!("{chunk_dir}/{{{{Task.Param.Start}}}}")),
                // A retried task replaces what a failed attempt left.
                q("--overwrite"),
                q("--quiet"),
            ];
            for o in &self.replay_options {
                match o {
                    ReplayOption::Flag(f) => args.push(q(f)),
                    ReplayOption::Value(k, v) => {
                        args.push(q(k));
                        args.push(q(v));
                    }
                    ReplayOption::File { option, param, .. } => {
                        args.push(q(option));
                        args.push(q(&format!("{{{{Param.{param}}}}}")));
                    }
                }
            }
            let _ = writeln!(y, "- name: {}", q(&format!("Chunks {}", t.name)));
            let _ = writeln!(
                y,
                "  description: {}",
                q(&format!(
                    "Take {}: {} chunks of frames, each replayed after its warm-up.",
                    t.name,
                    t.chunks.len()
                ))
            );
            let _ = writeln!(y, "  parameterSpace:\n    taskParameterDefinitions:");
            let _ = writeln!(
                y,
                "    - name: Start\n      type: INT\n      range: [{}]",
                starts.join(", ")
            );
            let _ = writeln!(
                y,
                "    - name: End\n      type: INT\n      range: [{}]",
                ends.join(", ")
            );
            let _ = writeln!(y, "    combination: '(Start, End)'");
            action(&mut y, &args);
            let merge_args = vec![
                q("farm"),
                q("merge"),
                q(&chunk_dir),
                q("--out"),
                q(&format!("{{{{Param.OutDir}}}}/{}", t.name)),
                q("--overwrite"),
            ];
            let _ = writeln!(y, "- name: {}", q(&format!("Merge {}", t.name)));
            let _ = writeln!(
                y,
                "  description: {}",
                q(&format!(
                    "Joins the chunks of take {} into one take folder.",
                    t.name
                ))
            );
            let _ = writeln!(
                y,
                "  dependencies:\n  - dependsOn: {}",
                q(&format!("Chunks {}", t.name))
            );
            action(&mut y, &merge_args);
        }
        let mut report_args = vec![q("report")];
        for t in &self.takes {
            report_args.push(q(&format!("{{{{Param.OutDir}}}}/{}", t.name)));
        }
        report_args.extend([q("--out"), q("{{Param.OutDir}}/report"), q("--quiet")]);
        let _ = writeln!(y, "- name: 'Report'");
        let _ = writeln!(
            y,
            "  description: {}",
            q("The dailies report of every take (HTML with plots).")
        );
        y.push_str("  dependencies:\n");
        for t in &self.takes {
            let _ = writeln!(y, "  - dependsOn: {}", q(&format!("Merge {}", t.name)));
        }
        action(&mut y, &report_args);
        y
    }

    /// The job parameters' values (`parameter_values.yaml`, the job bundle format of
    /// AWS Deadline Cloud).
    pub fn parameter_values(&self) -> String {
        let mut y = String::from("parameterValues:\n");
        let mut value = |name: &str, v: &str| {
            let _ = writeln!(y, "- name: {name}\n  value: {}", q(v));
        };
        value("HelmcapExe", &self.helmcap.to_string_lossy());
        value("OutDir", &self.out.to_string_lossy());
        for (i, t) in self.takes.iter().enumerate() {
            value(&session_param(i), &t.session.to_string_lossy());
        }
        for o in &self.replay_options {
            if let ReplayOption::File { param, path, .. } = o {
                value(param, &path.to_string_lossy());
            }
        }
        value("WarmUpFrames", &self.overlap.to_string());
        y
    }

    /// Writes `template.yaml` and `parameter_values.yaml` into `dir` (each atomically).
    ///
    /// # Errors
    /// A file that cannot be written.
    pub fn write(&self, dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        for (name, text) in [
            ("template.yaml", self.template()),
            ("parameter_values.yaml", self.parameter_values()),
        ] {
            crate::atomic_file::write_atomically(&dir.join(name), |w| {
                use std::io::Write;
                w.write_all(text.as_bytes())
            })?;
        }
        Ok(())
    }
}

/// The job parameter of take `i`'s session folder.
fn session_param(i: usize) -> String {
    format!("Take{}Session", i + 1)
}

fn param_path(y: &mut String, name: &str, object: &str, flow: &str, description: &str) {
    let _ = writeln!(
        y,
        "- name: {name}\n  type: PATH\n  objectType: {object}\n  dataFlow: {flow}\n  description: {}",
        q(description)
    );
}

/// A step's script: one action running the helmcap executable with `args` (quoted).
fn action(y: &mut String, args: &[String]) {
    let _ = writeln!(
        y,
        "  script:\n    actions:\n      onRun:\n        command: '{{{{Param.HelmcapExe}}}}'\n        args:"
    );
    for a in args {
        let _ = writeln!(y, "        - {a}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_tile_the_take_and_warm_up_within_it() {
        let c = chunk_ranges(10, 1509, 600, 60).unwrap();
        assert_eq!(
            c,
            vec![
                Chunk {
                    start: 10,
                    end: 610,
                    warm_up_from: 10
                },
                Chunk {
                    start: 610,
                    end: 1210,
                    warm_up_from: 550
                },
                Chunk {
                    start: 1210,
                    end: 1510,
                    warm_up_from: 1150
                },
            ]
        );
        assert_eq!(chunk_ranges(0, 0, 600, 60).unwrap().len(), 1);
        assert!(chunk_ranges(0, 10, 0, 60).is_err());
        assert!(chunk_ranges(5, 4, 10, 0).is_err());
    }

    fn spec() -> JobSpec {
        JobSpec {
            name: "day 1".into(),
            helmcap: "/opt/helmcap/bin/helmcap".into(),
            out: "/farm/out".into(),
            chunk: 40,
            takes: vec![
                JobTake {
                    name: "take_01".into(),
                    session: "/farm/sessions/take_01".into(),
                    chunks: chunk_ranges(0, 99, 40, 10).unwrap(),
                },
                JobTake {
                    name: "it's".into(),
                    session: "/farm/sessions/it's".into(),
                    chunks: chunk_ranges(0, 9, 40, 10).unwrap(),
                },
            ],
            overlap: 10,
            replay_options: vec![
                ReplayOption::Flag("--exact-bundles".into()),
                ReplayOption::Value("--export".into(), "usd".into()),
                ReplayOption::File {
                    option: "--calib".into(),
                    param: "Calib".into(),
                    path: "/farm/calib.yaml".into(),
                },
            ],
        }
    }

    #[test]
    fn template_has_the_steps_and_no_absolute_path() {
        let s = spec();
        s.validate().unwrap();
        let t = s.template();
        assert!(t.starts_with("specificationVersion: 'jobtemplate-2023-09'\n"));
        for step in [
            "- name: 'Chunks take_01'",
            "- name: 'Merge take_01'",
            "- name: 'Chunks it''s'",
            "- name: 'Report'",
        ] {
            assert!(t.contains(step), "{step} missing in\n{t}");
        }
        assert!(t.contains("range: [0, 40, 80]"));
        assert!(t.contains("range: [40, 80, 100]"));
        assert!(t.contains("- '{{Param.Calib}}'"));
        assert!(!t.contains("/farm"), "an absolute path in the template");
        let v = s.parameter_values();
        assert!(v.contains("- name: Take2Session\n  value: '/farm/sessions/it''s'"));
        assert!(v.contains("- name: Calib\n  value: '/farm/calib.yaml'"));
    }

    #[test]
    fn duplicate_or_unfit_take_names_are_refused() {
        let mut s = spec();
        s.takes[1].name = "take_01".into();
        assert!(s.validate().unwrap_err().to_string().contains("two takes"));
        let mut s = spec();
        s.takes[1].name = "x".repeat(70);
        assert!(s.validate().is_err());
        let mut s = spec();
        s.takes[1].name = "a/b".into();
        assert!(s.validate().is_err());
    }
}

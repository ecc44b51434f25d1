//! `helmcap register`: brings a scan of any topology into the template's topology by
//! optimal-step non-rigid ICP (Amberg et al. 2007).
//!
//! Landmarks CSV: header `vertex,x,y,z`; one row per landmark: a template vertex index and
//! its position on the scan (scan unit and frame).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::mesh::{read_mesh, write_obj_positions};
use helmcap::rig::{RegistrationParams, register};
use nalgebra::Point3;

/// Arguments of `helmcap register`.
#[derive(Debug, clap::Args)]
pub struct RegisterArgs {
    /// Template mesh (OBJ or PLY): its topology is kept.
    #[arg(long, value_name = "MESH")]
    pub template: PathBuf,
    /// Scan to fit (OBJ or PLY, any topology, same unit as the template).
    #[arg(long, value_name = "MESH")]
    pub scan: PathBuf,
    /// Landmarks CSV (`vertex,x,y,z`: template vertex, its position on the scan). With 3 or
    /// more, they also give the initial rigid alignment; without, the centroids are aligned.
    #[arg(long, value_name = "CSV")]
    pub landmarks: Option<PathBuf>,
    /// Output OBJ: the template's topology (and UVs) with the registered positions.
    #[arg(long, value_name = "OBJ")]
    pub out: PathBuf,
    /// Registration parameters (TOML, fields of `RegistrationParams`; missing fields keep
    /// their defaults).
    #[arg(long, value_name = "TOML")]
    pub params: Option<PathBuf>,
}

fn read_landmarks(path: &Path) -> anyhow::Result<Vec<(u32, Point3<f64>)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || (i == 0 && line.starts_with("vertex")) {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() < 4 {
            bail!("{}:{}: expected vertex,x,y,z", path.display(), i + 1);
        }
        let v: u32 = f[0]
            .parse()
            .with_context(|| format!("{}:{}: bad vertex {:?}", path.display(), i + 1, f[0]))?;
        let mut c = [0.0f64; 3];
        for (k, ck) in c.iter_mut().enumerate() {
            let field = f[k + 1];
            *ck = field.parse().with_context(|| {
                format!("{}:{}: bad coordinate {field:?}", path.display(), i + 1)
            })?;
            if !ck.is_finite() {
                bail!("{}:{}: coordinate is not finite", path.display(), i + 1);
            }
        }
        out.push((v, Point3::new(c[0], c[1], c[2])));
    }
    Ok(out)
}

/// Runs `helmcap register`.
pub fn run(args: RegisterArgs) -> anyhow::Result<()> {
    let params: RegistrationParams = match &args.params {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => RegistrationParams::default(),
    };
    params.validate()?;
    let template = read_mesh(&args.template)
        .with_context(|| format!("reading {}", args.template.display()))?;
    let scan = read_mesh(&args.scan).with_context(|| format!("reading {}", args.scan.display()))?;
    let landmarks = match &args.landmarks {
        Some(p) => read_landmarks(p)?,
        None => Vec::new(),
    };
    let total = (params.stiffness.len() * params.max_iterations) as u64;
    let bar = indicatif::ProgressBar::new(total);
    let mut done = 0u64;
    let mut last_stage = usize::MAX;
    let reg = register(
        &template,
        &scan,
        &landmarks,
        &params,
        &mut |stage, it, rms| {
            if stage != last_stage {
                done = (stage * params.max_iterations) as u64;
                last_stage = stage;
            }
            done += 1;
            bar.set_position(done);
            bar.set_message(format!(
                "stiffness {} iteration {} rms {rms:.3}",
                params.stiffness[stage],
                it + 1
            ));
        },
    )
    .context("registering the scan")?;
    bar.finish_and_clear();
    write_obj_positions(&args.out, &template, &reg.positions)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "registered {} template vertices onto {} ({} iterations): {:.1} % matched, surface RMS {:.4} (scan unit); wrote {}",
        template.vertex_count(),
        args.scan.display(),
        reg.iterations,
        reg.matched_fraction * 100.0,
        reg.rms_distance,
        args.out.display()
    );
    Ok(())
}

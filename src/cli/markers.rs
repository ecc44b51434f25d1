//! `helmcap markers generate`.

use std::path::PathBuf;

use anyhow::Context;
use clap::Subcommand;
use helmcap::dataset::manifest::parse_vertex_range;
use helmcap::dataset::markers::{LayoutParams, generate_layout};

use super::DatasetArgs;

#[derive(Debug, Subcommand)]
pub enum MarkersCommand {
    /// Generate a marker layout for a dataset: evenly spread over the paintable face, each
    /// marker weighted for head stabilization by how little it moves.
    Generate {
        #[command(flatten)]
        dataset: DatasetArgs,
        /// Number of markers.
        #[arg(long, short = 'n', default_value_t = LayoutParams::default().count)]
        count: usize,
        /// Keep markers this far (mm, along the mesh) from eyelid margins, lips' inner edge
        /// and the border of the face area.
        #[arg(long, default_value_t = LayoutParams::default().min_border_distance_mm)]
        min_border_distance: f64,
        /// Largest angle (degrees) between a marker's normal and the camera direction (+z).
        #[arg(long, default_value_t = LayoutParams::default().max_view_angle_deg)]
        max_view_angle: f64,
        /// Restrict markers to these vertices (inclusive range "A..B") within the dataset's
        /// face vertices; e.g. 0..6705 for the ICT face without ears and neck.
        #[arg(long, value_name = "A..B")]
        region: Option<String>,
        /// Output CSV (name,vertex,stabilize_weight).
        #[arg(long, short)]
        out: PathBuf,
    },
}

pub fn run(cmd: MarkersCommand) -> anyhow::Result<()> {
    match cmd {
        MarkersCommand::Generate {
            dataset,
            count,
            min_border_distance,
            max_view_angle,
            region,
            out,
        } => {
            let region = region
                .map(|r| {
                    parse_vertex_range(&r)
                        .with_context(|| format!("--region {r:?} is not a range like 0..6705"))
                })
                .transpose()?;
            let ds = dataset.load()?;
            let params = LayoutParams {
                count,
                min_border_distance_mm: min_border_distance,
                max_view_angle_deg: max_view_angle,
                region,
                ..LayoutParams::default()
            };
            let layout = generate_layout(&ds, &params)
                .with_context(|| format!("generating markers for {}", ds.name))?;
            layout
                .write_csv(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            let stable = layout.stabilizing_count();
            println!(
                "wrote {} markers to {} ({} with stabilize_weight >= 0.5)",
                layout.len(),
                out.display(),
                stable
            );
            Ok(())
        }
    }
}

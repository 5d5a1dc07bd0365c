//! Writes every table (all formats) and the datasize and Pareto figures of the
//! paper data into a directory: `cargo run -p d3il-tables --example
//! render_paper -- OUT_DIR`. Handy for looking at the output by eye.

use d3il_protocol::{paper, ObsType};
use d3il_tables::{render_figure, render_table, FigureKind, Format, SourceFilter, TableKind};
use std::collections::BTreeMap;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or("usage: render_paper OUT_DIR")?,
    );
    std::fs::create_dir_all(&out)?;
    let cells = paper::load_embedded().cells();
    for kind in TableKind::ALL {
        for obs in [ObsType::State, ObsType::Image] {
            for format in Format::ALL {
                match render_table(&cells, kind, obs, format, SourceFilter::Reported) {
                    Ok(s) => {
                        std::fs::write(out.join(format!("{kind}-{obs}.{}", format.extension())), s)?
                    }
                    Err(e) => eprintln!("{kind} {obs}: {e}"),
                }
            }
        }
    }
    for (kind, obs) in [
        (FigureKind::Datasize, ObsType::State),
        (FigureKind::Pareto, ObsType::State),
        (FigureKind::Pareto, ObsType::Image),
    ] {
        let svg = render_figure(&cells, kind, obs, SourceFilter::Reported, &BTreeMap::new())?;
        std::fs::write(out.join(format!("{kind}-{obs}.svg")), svg)?;
    }
    // Synthetic Avoiding paths through every corridor combination (the
    // figure of a real submission comes from `d3il tables --figure avoiding-paths`).
    let mut paths = Vec::new();
    for (b1, x1) in [(1, 0.43f32), (2, 0.57)] {
        for (b2, x2) in [(4, 0.36f32), (8, 0.5), (16, 0.64)] {
            for (b3, x3) in [(32, 0.28f32), (64, 0.425), (128, 0.575), (256, 0.72)] {
                let waypoints = [
                    (0.525f32, -0.28f32),
                    (x1, -0.1),
                    (x2, 0.08),
                    (x3, 0.26),
                    (x3, 0.36),
                ];
                let mut p = Vec::new();
                for w in waypoints.windows(2) {
                    for k in 0..10 {
                        let t = k as f32 / 10.0;
                        p.push([
                            w[0].0 + t * (w[1].0 - w[0].0),
                            w[0].1 + t * (w[1].1 - w[0].1),
                        ]);
                    }
                }
                p.push([x3, 0.36]);
                paths.push((serde_json::json!(b1 + b2 + b3), p));
            }
        }
    }
    let svg = d3il_tables::render_avoiding_paths(&paths, "Avoiding: synthetic corridor paths")?;
    std::fs::write(out.join("avoiding-paths-synthetic.svg"), svg)?;
    Ok(())
}

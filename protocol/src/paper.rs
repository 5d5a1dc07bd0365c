//! Serde model of `assets/paper-results.json` (the D3IL paper's published results).

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperResults {
    pub source: String,
    pub notes: String,
    /// Method name -> properties. Order in the paper is given by [`PAPER_METHOD_ORDER`].
    pub methods: BTreeMap<String, PaperMethod>,
    pub protocol: serde_json::Value,
    pub results: Vec<PaperRow>,
}

/// The paper's row order of the eleven baselines.
pub const PAPER_METHOD_ORDER: [&str; 11] = [
    "BC-MLP",
    "VAE-State",
    "BeT-MLP",
    "IBC",
    "DDPM-MLP",
    "VAE-ACT",
    "BC-GPT",
    "BeT",
    "DDPM-GPT",
    "BESO",
    "DDPM-ACT",
];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperMethod {
    pub history: u32,
    pub backbone: String,
    pub prediction: String,
    pub diversity: String,
    pub inference_ms: InferenceMs,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InferenceMs {
    pub state_ms: f64,
    pub image_ms: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperStat {
    pub mean: f64,
    pub std: f64,
    pub bold: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperRow {
    pub table: String,
    pub obs: String,
    pub task: String,
    pub method: String,
    pub data_fraction: f64,
    #[serde(default)]
    pub control: Option<String>,
    pub success_rate: PaperStat,
    pub entropy: PaperStat,
    pub seeds: usize,
    #[serde(default)]
    pub subtasks: Option<serde_json::Value>,
}

/// The paper data embedded in the binary.
pub const PAPER_RESULTS_JSON: &str = include_str!("../../assets/paper-results.json");

pub fn load_embedded() -> PaperResults {
    serde_json::from_str(PAPER_RESULTS_JSON).expect("embedded paper results are valid JSON")
}

impl PaperResults {
    /// The reported rows as table cells.
    pub fn cells(&self) -> Vec<crate::results::ResultCell> {
        self.results
            .iter()
            .map(|r| crate::results::ResultCell {
                table: r.table.clone(),
                method: r.method.clone(),
                task: r.task.clone(),
                obs: if r.obs == "image" {
                    crate::task::ObsType::Image
                } else {
                    crate::task::ObsType::State
                },
                data_fraction: r.data_fraction,
                control: r.control.clone(),
                source: crate::results::Source::Reported,
                success_rate: crate::results::Stat {
                    mean: r.success_rate.mean,
                    std: r.success_rate.std,
                },
                entropy: crate::results::Stat {
                    mean: r.entropy.mean,
                    std: r.entropy.std,
                },
                n_seeds: r.seeds,
                bold_success: Some(r.success_rate.bold),
                bold_entropy: Some(r.entropy.bold),
                initial_states: None,
                robot_look: None,
                build: None,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn embedded_paper_results_parse_and_cover_all_tables() {
        let p = super::load_embedded();
        assert_eq!(p.methods.len(), 11);
        for m in super::PAPER_METHOD_ORDER {
            assert!(p.methods.contains_key(m), "{m}");
        }
        let cells = p.cells();
        assert_eq!(cells.len(), 238);
        for t in ["main", "datasize", "posvel", "prelim"] {
            assert!(cells.iter().any(|c| c.table == t), "{t}");
        }
    }
}

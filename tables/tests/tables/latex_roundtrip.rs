//! Must show: from the paper data alone, the main state (and image) LaTeX
//! table reproduces every number of the paper's table. The generated LaTeX is
//! parsed back and compared with the paper JSON read directly from the assets
//! file (not through d3il-protocol's conversion), including bold and marks.

use d3il_protocol::{paper, ObsType};
use d3il_tables::{render_table, Format, SourceFilter, TableKind};
use std::collections::BTreeMap;

#[derive(Debug, PartialEq)]
struct Parsed {
    mean: f64,
    std: f64,
    bold: bool,
}

/// (method, task, metric) -> value; plus the method order per block and marks.
struct ParsedTable {
    values: BTreeMap<(String, String, &'static str), Parsed>,
    block_orders: Vec<Vec<String>>,
    marks: BTreeMap<String, String>,
}

fn parse_cell(cell: &str) -> Parsed {
    // `$MEAN {\scriptstyle \pm STD}$` or `$\mathbf{MEAN} {\scriptstyle \pm STD}$`
    let inner = cell
        .strip_prefix('$')
        .and_then(|c| c.strip_suffix('$'))
        .unwrap_or_else(|| panic!("cell is not math: {cell}"));
    let (mean_part, std_part) = inner
        .split_once(" {\\scriptstyle \\pm ")
        .unwrap_or_else(|| panic!("no scriptstyle pm in {cell}"));
    let std_text = std_part.strip_suffix('}').expect("closing brace");
    let (bold, mean_text) = match mean_part.strip_prefix("\\mathbf{") {
        Some(m) => (true, m.strip_suffix('}').expect("mathbf brace")),
        None => (false, mean_part),
    };
    Parsed {
        mean: mean_text
            .parse()
            .unwrap_or_else(|e| panic!("{mean_text}: {e}")),
        std: std_text
            .parse()
            .unwrap_or_else(|e| panic!("{std_text}: {e}")),
        bold,
    }
}

fn parse_latex(tex: &str) -> ParsedTable {
    let mut values = BTreeMap::new();
    let mut block_orders = Vec::new();
    let mut marks = BTreeMap::new();
    let mut tasks: Vec<String> = Vec::new();
    for line in tex.lines() {
        if let Some(rest) = line.strip_prefix(" & \\multicolumn") {
            tasks = rest
                .split("\\multicolumn")
                .map(|p| {
                    let start = p.find("{c}{").expect("multicolumn title") + 4;
                    let end = p.rfind('}').expect("closing");
                    p[start..end].to_string()
                })
                .collect();
            block_orders.push(Vec::new());
            continue;
        }
        let Some(body) = line.strip_suffix(" \\\\") else {
            continue;
        };
        if body.starts_with("Method &") || !body.contains(" & ") {
            continue;
        }
        let cells: Vec<&str> = body.split(" & ").collect();
        let (method, mark) = match cells[0].split_once("$^{") {
            Some((m, rest)) => (m.to_string(), rest.trim_end_matches("}$").to_string()),
            None => (cells[0].to_string(), String::new()),
        };
        assert_eq!(cells.len(), 1 + 2 * tasks.len(), "row {line}");
        for (i, task) in tasks.iter().enumerate() {
            for (j, metric) in ["success_rate", "entropy"].into_iter().enumerate() {
                let v = parse_cell(cells[1 + 2 * i + j]);
                let old = values.insert((method.clone(), task.clone(), metric), v);
                assert!(old.is_none(), "{method} {task} {metric} twice");
            }
        }
        block_orders
            .last_mut()
            .expect("row before header")
            .push(method.clone());
        marks.insert(method, mark);
    }
    ParsedTable {
        values,
        block_orders,
        marks,
    }
}

fn paper_json() -> serde_json::Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/paper-results.json");
    let text = std::fs::read_to_string(path).expect("paper results asset");
    serde_json::from_str(&text).expect("paper JSON")
}

fn check_main(obs: ObsType, expected_rows: usize) {
    let cells = paper::load_embedded().cells();
    let tex = render_table(
        &cells,
        TableKind::Main,
        obs,
        Format::Latex,
        SourceFilter::Reported,
    )
    .expect("render");
    let parsed = parse_latex(&tex);
    let json = paper_json();
    let rows: Vec<&serde_json::Value> = json["results"]
        .as_array()
        .expect("results array")
        .iter()
        .filter(|r| r["table"] == "main" && r["obs"] == obs.as_str())
        .collect();
    assert_eq!(rows.len(), expected_rows);
    // Every number of the paper's table is in the LaTeX, and nothing else.
    assert_eq!(parsed.values.len(), 2 * rows.len());
    for r in rows {
        let method = r["method"].as_str().expect("method").to_string();
        let task = r["task"].as_str().expect("task").to_string();
        for metric in ["success_rate", "entropy"] {
            let want = Parsed {
                mean: r[metric]["mean"].as_f64().expect("mean"),
                std: r[metric]["std"].as_f64().expect("std"),
                bold: r[metric]["bold"].as_bool().expect("bold"),
            };
            let got = parsed
                .values
                .get(&(method.clone(), task.clone(), metric))
                .unwrap_or_else(|| panic!("{method} {task} {metric} missing from the LaTeX"));
            assert_eq!(got, &want, "{method} {task} {metric}");
        }
    }
    // Rows in the paper's order in every block, with the paper's marks.
    for order in &parsed.block_orders {
        assert_eq!(order, &paper::PAPER_METHOD_ORDER.map(String::from).to_vec());
    }
    for (method, mark) in &parsed.marks {
        let want = match method.as_str() {
            "VAE-ACT" => "\\dagger",
            "DDPM-ACT" => "\\dagger\\ddagger",
            "BC-GPT" | "BeT" | "DDPM-GPT" | "BESO" => "\\ddagger",
            _ => "",
        };
        assert_eq!(mark, want, "marks of {method}");
    }
    // Booktabs layout and a caption with the protocol and the seeds.
    for needle in [
        "\\toprule",
        "\\midrule",
        "\\bottomrule",
        "\\cmidrule(lr){2-3}",
        "over 6 training seeds",
        "60 initial states $\\times$ 18 rollouts",
    ] {
        assert!(tex.contains(needle), "missing {needle}");
    }
}

#[test]
fn main_state_latex_reproduces_every_number_of_the_paper() {
    check_main(ObsType::State, 99);
}

#[test]
fn main_image_latex_reproduces_every_number_of_the_paper() {
    check_main(ObsType::Image, 66);
}

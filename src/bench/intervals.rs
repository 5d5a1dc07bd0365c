//! `d3il bench intervals`: simulated coverage of every interval the service
//! prints (docs/intervals.md): the success rate's rule and the difference of
//! success rates (d3il_metrics::intervals, d3il_metrics::rate_difference:
//! the exact McNemar test with one rollout a state, the sign-flip test with
//! more, the two-sample score test on one initial state) next to what the
//! service printed up to 0.4 (the bias-corrected two-stage bootstrap of a
//! success rate, the paired bootstrap of `d3il compare`), on a grid of true
//! rates, initial states and rollouts per state; then the entropies' and the
//! robustness scores' bootstrap intervals (d3il_metrics::interval_sim has
//! the models). The last line is the minimum coverage of each kind: success
//! rates and their differences (over the cells given an interval), the
//! entropies, the scores, and the 0.4 methods, with the ratio of the first
//! to the nominal 95 % (the 0.4 methods' minimum is 0: width-0 intervals).
//! The score cells are those whose figures label the scores' intervals on
//! the pages, the API and the tables (d3il_protocol::interval::
//! SCORE_COVERAGE_MEASURED); a line after the tables says whether this run
//! still gives them.

use d3il_metrics::interval_sim::{
    simulate_cell, simulate_entropy_cell, simulate_score_cell, Cell, Design, Kind,
};
use d3il_metrics::EntropyConvention;
use d3il_protocol::interval::{
    score_coverage_min_states, SCORE_COVERAGE_MEASURED, SCORE_COVERAGE_REPLICATIONS,
};
use d3il_protocol::TaskId;

const CONFIDENCE: f64 = 0.95;
const RATES: [f64; 5] = [0.05, 0.2, 0.5, 0.8, 0.95];
/// The grid and 120, where the success rate's bootstrap rule applies.
const STATES: [usize; 5] = [3, 10, 30, 60, 120];
const ROLLOUTS: [usize; 2] = [1, 8];
/// Single rate, two exchangeable policies (difference 0), and B at three
/// quarters of A's rate on every state.
const DESIGNS: [(Design, &str); 3] = [
    (Design::Single, "single"),
    (Design::Paired { ratio: 1.0 }, "paired r=1"),
    (Design::Paired { ratio: 0.75 }, "paired r=0.75"),
];
/// One initial state (Avoiding): the quick protocol's 8 rollouts and the
/// paper's 480.
const ONE_STATE: [(Design, &str); 2] = [
    (Design::TwoSample { ratio: 1.0 }, "1 state r=1"),
    (Design::TwoSample { ratio: 0.75 }, "1 state r=0.75"),
];
const ONE_STATE_ROLLOUTS: [usize; 2] = [8, 480];

/// The entropy cells: a name, the kinds of state, the task whose
/// convention applies, states × rollouts.
fn entropy_cells(smoke: bool) -> Vec<(&'static str, Vec<Kind>, TaskId, usize, usize)> {
    let kind = |success: f64, behaviours: &[f64]| Kind {
        success,
        behaviours: behaviours.to_vec(),
    };
    let aligning = vec![
        kind(0.9, &[0.8, 0.2]),
        kind(0.6, &[0.65, 0.35]),
        kind(0.75, &[0.3, 0.7]),
    ];
    if smoke {
        return vec![("aligning-like", aligning, TaskId::Aligning, 10, 4)];
    }
    let pushing = vec![
        kind(0.8, &[0.4, 0.3, 0.2, 0.1]),
        kind(0.5, &[0.1, 0.2, 0.3, 0.4]),
    ];
    let sorting = vec![
        kind(0.4, &[0.5, 0.2, 0.1, 0.1, 0.05, 0.05]),
        kind(0.7, &[0.2, 0.2, 0.2, 0.2, 0.1, 0.1]),
    ];
    let avoiding = vec![kind(0.85, &[0.3, 0.2, 0.15, 0.1, 0.1, 0.05, 0.05, 0.05])];
    vec![
        ("aligning-like", aligning.clone(), TaskId::Aligning, 3, 8),
        ("aligning-like", aligning.clone(), TaskId::Aligning, 10, 8),
        ("aligning-like", aligning, TaskId::Aligning, 60, 8),
        ("pushing-like", pushing, TaskId::Pushing, 30, 16),
        ("sorting-like", sorting, TaskId::Sorting4, 60, 18),
        ("avoiding-like", avoiding, TaskId::Avoiding, 1, 480),
    ]
}

pub fn run(smoke: bool) -> anyhow::Result<()> {
    // Smoke: a few replications of a corner of each grid.
    let (reps, resamples, truth_runs) = if smoke {
        (10, 200, 20)
    } else {
        (400, 1000, 2000)
    };
    let rates: &[f64] = if smoke { &[0.2, 0.95] } else { &RATES };
    let states: &[usize] = if smoke { &[3, 10] } else { &STATES };
    let started = std::time::Instant::now();
    println!(
        "coverage of {:.0} % intervals, {reps} replications a cell ({resamples} bootstrap resamples / sign vectors); Monte-Carlo standard error at 95 %: {:.1} points",
        CONFIDENCE * 100.0,
        100.0 * (CONFIDENCE * (1.0 - CONFIDENCE) / reps as f64).sqrt()
    );
    println!(
        "{:<14} {:>5} {:>6} {:>5} {:>7} | {:>8} {:>6} {:>5} {:>4} {:>4} | {:>8} {:>6} {:>4} {:>4}",
        "design",
        "rate",
        "states",
        "roll",
        "truth",
        "new cov",
        "width",
        "given",
        "w=0",
        "dis",
        "cur cov",
        "width",
        "w=0",
        "dis"
    );
    let (mut min_new, mut min_cur, mut min_cur_same) =
        (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let mut below = Vec::new();
    let mut seed = 0u64;
    let mut cells = Vec::new();
    for (design, name) in DESIGNS {
        for &rate in rates {
            for &n in states {
                for &m in &ROLLOUTS {
                    cells.push((design, name, rate, n, m));
                }
            }
        }
    }
    for (design, name) in ONE_STATE {
        for &rate in rates {
            for &m in &ONE_STATE_ROLLOUTS[..if smoke { 1 } else { 2 }] {
                cells.push((design, name, rate, 1, m));
            }
        }
    }
    for (design, name, rate, n, m) in cells {
        seed += 1;
        let cell = Cell {
            rate,
            states: n,
            rollouts: m,
            design,
        };
        let c = simulate_cell(&cell, reps, resamples, CONFIDENCE, seed);
        let cur = c.current_coverage();
        min_cur = min_cur.min(cur);
        let new = match c.new_coverage() {
            Some(v) => {
                min_new = min_new.min(v);
                min_cur_same = min_cur_same.min(cur);
                if v < 0.94 {
                    below.push(format!("{name} rate {rate} {n}x{m}: {v:.3}"));
                }
                format!("{v:.3}")
            }
            None => "none".into(),
        };
        let width = if c.new_given > 0 {
            format!("{:.3}", c.new_width_sum / c.new_given as f64)
        } else {
            "-".into()
        };
        let paired = !matches!(design, Design::Single);
        let dis = |x: usize| {
            if paired {
                x.to_string()
            } else {
                "-".into()
            }
        };
        println!(
            "{:<14} {:>5.2} {:>6} {:>5} {:>+7.3} | {:>8} {:>6} {:>5} {:>4} {:>4} | {:>8.3} {:>6.3} {:>4} {:>4}",
            name,
            rate,
            n,
            m,
            cell.truth(),
            new,
            width,
            format!("{:.0}%", 100.0 * c.new_given as f64 / reps as f64),
            c.new_zero_width,
            dis(c.new_disagree),
            cur,
            c.current_width_sum / reps as f64,
            c.current_zero_width,
            dis(c.current_disagree),
        );
    }
    println!(
        "columns: new = this version's interval (d3il_metrics::intervals, rate_difference), cur = the service's up to 0.4; cov = coverage (new: among the replications given an interval), given = share of replications given one (none: never, fewer than 5 states or a paired test that cannot reject; below 100 %: every state showed the same difference, sign-flip test), w=0 = intervals of width 0, dis = replications whose interval and p-value disagree about 0"
    );

    // Entropies: the two-stage bootstrap, for the statistic's expectation at
    // the protocol's size.
    println!(
        "\nentropies (two-stage bootstrap, bias-corrected; for the expected plug-in entropy at this size, {truth_runs} datasets):"
    );
    println!(
        "{:<14} {:>10} {:>8} | {:>7} {:>8} {:>6} {:>4} | {:>7} {:>8} {:>6} {:>4}",
        "model",
        "task",
        "states",
        "H truth",
        "H cov",
        "width",
        "w=0",
        "Hc trth",
        "Hc cov",
        "width",
        "w=0"
    );
    let mut min_entropy = f64::INFINITY;
    for (name, kinds, task, n, m) in entropy_cells(smoke) {
        seed += 1;
        let conv = EntropyConvention::for_task(task);
        let (cov, t) =
            simulate_entropy_cell(&kinds, &conv, n, m, reps, resamples, truth_runs, seed);
        for (what, c) in ["behaviour", "conditional"].iter().zip(&cov) {
            min_entropy = min_entropy.min(c.coverage());
            if c.coverage() < 0.94 {
                below.push(format!(
                    "{what} entropy {name} {n}x{m}: {:.3}",
                    c.coverage()
                ));
            }
        }
        println!(
            "{:<14} {:>10} {:>8} | {:>7.3} {:>8.3} {:>6.3} {:>4} | {:>7.3} {:>8.3} {:>6.3} {:>4}",
            name,
            task.to_string(),
            format!("{n}x{m}"),
            t[0],
            cov[0].coverage(),
            cov[0].mean_width(),
            cov[0].zero_width,
            t[1],
            cov[1].coverage(),
            cov[1].mean_width(),
            cov[1].zero_width,
        );
    }

    // Robustness scores: the paired bootstrap over states, for the score's
    // expectation at this size; beside it, how often it covers the
    // population's score (which no finite protocol measures).
    println!(
        "\nrobustness scores (one axis, 3 levels at ratio^l of level 0's rate; paired bootstrap, bias-corrected; for the expected score at this size, {truth_runs} datasets):"
    );
    println!(
        "{:>5} {:>6} {:>8} | {:>7} {:>8} {:>6} {:>4} | {:>7} {:>8}",
        "rate", "ratio", "states", "truth", "cov", "width", "w=0", "popul.", "pop cov"
    );
    let mut min_score = f64::INFINITY;
    // The cells whose figures label the scores' intervals on the pages
    // (d3il_protocol::interval::SCORE_COVERAGE_MEASURED), in its order.
    let score_cells: Vec<(f64, usize, usize)> = if smoke {
        vec![(0.8, 10, 2)]
    } else {
        SCORE_COVERAGE_MEASURED
            .iter()
            .map(|c| (c.rate_percent as f64 / 100.0, c.states, c.rollouts))
            .collect()
    };
    let mut label_figures = Vec::new();
    for (rate, n, m) in score_cells {
        seed += 1;
        let ratio = 0.75;
        let (cov, t) = simulate_score_cell(rate, ratio, 3, n, m, reps, resamples, truth_runs, seed);
        min_score = min_score.min(cov[0].coverage());
        label_figures.push((rate, n, m, cov[0].coverage()));
        if cov[0].coverage() < 0.94 {
            below.push(format!(
                "robustness score rate {rate} {n}x{m}: {:.3}",
                cov[0].coverage()
            ));
        }
        println!(
            "{:>5.2} {:>6.2} {:>8} | {:>7.3} {:>8.3} {:>6.3} {:>4} | {:>7.3} {:>8.3}",
            rate,
            ratio,
            format!("{n}x{m}"),
            t[0],
            cov[0].coverage(),
            cov[0].mean_width(),
            cov[0].zero_width,
            t[1],
            cov[1].coverage(),
        );
    }

    if !smoke {
        println!("{}", compare_label_figures(&label_figures, reps));
    }

    if below.is_empty() {
        println!("every coverage is at least 0.94");
    } else {
        println!("coverage below 0.94: {}", below.join("; "));
    }
    println!(
        "0.4 method's minimum over the cells the new one covers: {min_cur_same:.3}; {:.0} s",
        started.elapsed().as_secs_f64()
    );
    println!(
        "min coverage rates+differences {min_new:.3} entropies {min_entropy:.3} scores {min_score:.3} (0.4's rates+differences {min_cur:.3}); rates+differences to nominal ratio {:.3}",
        min_new / CONFIDENCE
    );
    Ok(())
}

/// Whether this run's score cells (rate, states, rollouts, coverage) give
/// the figures the pages label score intervals with
/// (`SCORE_COVERAGE_MEASURED`, as printed: three decimals).
fn compare_label_figures(run: &[(f64, usize, usize, f64)], reps: usize) -> String {
    let stored = &SCORE_COVERAGE_MEASURED;
    let mut differ = Vec::new();
    for (c, &(rate, n, m, cov)) in stored.iter().zip(run) {
        let printed = format!("{cov:.3}");
        if format!("{:.3}", c.coverage()) != printed
            || (rate, n, m) != (c.rate_percent as f64 / 100.0, c.states, c.rollouts)
        {
            differ.push(format!(
                "rate {rate} {n}x{m}: stored {:.3}, this run {printed}",
                c.coverage()
            ));
        }
    }
    if run.len() != stored.len() || reps != SCORE_COVERAGE_REPLICATIONS {
        differ.push(format!(
            "{} cells of {reps} replications here, {} of {} stored",
            run.len(),
            stored.len(),
            SCORE_COVERAGE_REPLICATIONS
        ));
    }
    if differ.is_empty() {
        format!(
            "score interval labels (d3il_protocol::interval::SCORE_COVERAGE_MEASURED): this run gives the stored figures; labelled below {} initial states",
            score_coverage_min_states()
        )
    } else {
        format!(
            "score interval labels (d3il_protocol::interval::SCORE_COVERAGE_MEASURED) differ from this run, update them: {}",
            differ.join("; ")
        )
    }
}

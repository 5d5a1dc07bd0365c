//! `d3il bench intervals`: simulated coverage of the intervals of issue 51
//! (d3il_metrics::intervals: the success-rate rule and the inverted
//! sign-flip paired interval) next to the ones the service prints today
//! (the bias-corrected two-stage bootstrap of a success rate, the paired
//! bootstrap of `d3il compare`), on a grid of true rates, initial states and
//! rollouts per state, single and paired (d3il_metrics::interval_sim has the
//! model). The last line is the minimum coverage of the new methods (over
//! the cells where they give an interval) and of the current ones (every
//! cell, as the service prints an interval everywhere). docs/intervals.md
//! has the method and a measured table.

use d3il_metrics::interval_sim::{simulate_cell, Cell, Design};

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

pub fn run(smoke: bool) -> anyhow::Result<()> {
    // Smoke: a few replications of a corner of the grid.
    let (reps, resamples) = if smoke { (10, 200) } else { (400, 1000) };
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
    for (design, name) in DESIGNS {
        for &rate in rates {
            for &n in states {
                for &m in &ROLLOUTS {
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
                    let paired = matches!(design, Design::Paired { .. });
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
            }
        }
    }
    println!(
        "columns: new = d3il_metrics::intervals, cur = the service's current interval; cov = coverage (new: among the replications given an interval), given = share of replications given one (none: never, fewer than 5 states or a paired test that cannot reject; below 100 %: every state showed the same paired difference), w=0 = intervals of width 0, dis = replications whose interval and p-value disagree about 0"
    );
    if below.is_empty() {
        println!("every new coverage is at least 0.94");
    } else {
        println!("new coverage below 0.94: {}", below.join("; "));
    }
    println!(
        "current method's minimum over the cells the new one covers: {min_cur_same:.3}; {:.0} s",
        started.elapsed().as_secs_f64()
    );
    println!(
        "min coverage new {min_new:.3} current {min_cur:.3} ratio {:.2}",
        min_new / min_cur
    );
    Ok(())
}

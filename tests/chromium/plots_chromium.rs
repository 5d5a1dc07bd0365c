//! Headless Chromium (Debian's `chromium`, installed by ./dev) renders the
//! plots `d3il serve` serves, and we read the screenshot's pixels: every
//! method's colour of the one palette is drawn, once in the legend column and
//! once among the data, and the leaderboard page at 1400 px shows the plot.

use crate::D3IL;
use d3il_protocol::paper::PAPER_METHOD_ORDER;
use d3il_tables::plot::method_colour;
use d3il_test_support::chromium::{chromium, HEADLESS};
use d3il_test_support::server::*;
use std::path::Path;
use std::process::Command;

/// Screenshot of `url` in a `w`×`h` window: (width, height, RGBA pixels).
fn screenshot(url: &str, (w, h): (u32, u32), dir: &Path, name: &str) -> (usize, usize, Vec<u8>) {
    let out = dir.join(format!("{name}.png"));
    let run = Command::new(chromium())
        .args(HEADLESS)
        .arg("--hide-scrollbars")
        .arg(format!(
            "--user-data-dir={}",
            dir.join(format!("profile-{name}")).display()
        ))
        .arg(format!("--window-size={w},{h}"))
        .arg(format!("--screenshot={}", out.display()))
        .arg(url)
        .output()
        .expect("run chromium");
    assert!(
        run.status.success() && out.exists(),
        "chromium failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let mut reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let rgba: Vec<u8> = buf[..info.buffer_size()]
        .chunks(channels)
        .flat_map(|p| [p[0], p[1], p[2], if channels == 4 { p[3] } else { 255 }])
        .collect();
    (info.width as usize, info.height as usize, rgba)
}

/// x coordinates of the pixels within 8 levels of `c` per channel.
fn columns_of(w: usize, rgba: &[u8], c: (u8, u8, u8)) -> Vec<usize> {
    let near = |a: u8, b: u8| a.abs_diff(b) <= 8;
    rgba.chunks(4)
        .enumerate()
        .filter(|(_, p)| near(p[0], c.0) && near(p[1], c.1) && near(p[2], c.2))
        .map(|(i, _)| i % w)
        .collect()
}

#[test]
fn chromium_draws_each_method_in_its_colour_with_the_legend_beside_the_data() {
    let dir = TempDir::new("plots-chromium");
    let server = D3IL.serve(&dir.path().join("lb.sqlite"), &["--workers", "0"]);
    let (s, svg) = server.get_text_blocking("/plots/tasks/avoiding/pareto.svg?obs=state");
    assert_eq!(s, 200);
    // Where the legend column starts, from the SVG's legend frame.
    let legend_x: f64 = svg
        .split("<g class=\"legend\">")
        .nth(1)
        .and_then(|g| g.split("x=\"").nth(1))
        .and_then(|x| x.split('"').next())
        .and_then(|x| x.parse().ok())
        .expect("legend frame");
    let (w, h, px) = screenshot(
        &format!("{}/plots/tasks/avoiding/pareto.svg?obs=state", server.base),
        (1000, 700),
        dir.path(),
        "pareto",
    );
    assert!(w >= 1000 && h >= 700);
    for m in PAPER_METHOD_ORDER {
        let c = method_colour(m);
        let xs = columns_of(w, &px, (c.0, c.1, c.2));
        let (legend, data): (Vec<usize>, Vec<usize>) =
            xs.iter().partition(|&&x| x as f64 >= legend_x);
        assert!(
            legend.len() >= 10,
            "{m}: its legend marker is not drawn ({} px)",
            legend.len()
        );
        assert!(
            data.len() >= 10,
            "{m}: its point is not drawn ({} px)",
            data.len()
        );
    }

    // The leaderboard page at 1400 px embeds the same plot.
    let (w, _, px) = screenshot(
        &format!("{}/tasks/avoiding", server.base),
        (1400, 2600),
        dir.path(),
        "board",
    );
    let drawn = PAPER_METHOD_ORDER
        .iter()
        .filter(|m| {
            let c = method_colour(m);
            columns_of(w, &px, (c.0, c.1, c.2)).len() >= 20
        })
        .count();
    assert_eq!(
        drawn,
        PAPER_METHOD_ORDER.len(),
        "method colours on the page"
    );
    server.kill();
}

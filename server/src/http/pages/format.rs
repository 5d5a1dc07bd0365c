//! How the pages print numbers, times and links.

use d3il_protocol::Stat;

/// A statistic over `n` seeds as every page prints it: the tables crate's one
/// number format (three decimals, `± std` only with n >= 2).
pub fn fmt_stat(s: Stat, n: usize) -> String {
    d3il_tables::mean_std(s.mean, s.std, n)
}

/// [`fmt_stat`] with the number of seeds shown after the spread (`(n = 3)`),
/// for cells without a seeds column.
pub fn fmt_stat_n(s: Stat, n: usize) -> String {
    let v = fmt_stat(s, n);
    if n >= 2 {
        format!("{v} (n = {n})")
    } else {
        v
    }
}

/// One number as the pages print it (three decimals).
pub fn fmt_num(x: f64) -> String {
    if x.is_finite() {
        d3il_tables::three_decimals(x)
    } else {
        "—".into()
    }
}

pub fn fmt_opt_ms(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.2}"),
        _ => "—".into(),
    }
}

pub fn fmt_time(t: i64) -> String {
    // Civil date from unix days (Howard Hinnant's algorithm), UTC.
    let days = t.div_euclid(86_400);
    let secs = t.rem_euclid(86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        secs / 3600,
        (secs % 3600) / 60
    )
}

pub fn fmt_duration(s: i64) -> String {
    if s < 90 {
        format!("{s} s")
    } else if s < 5400 {
        format!("{} min", (s + 30) / 60)
    } else {
        format!("{:.1} h", s as f64 / 3600.0)
    }
}

fn url_component(s: &str) -> String {
    url::form_urlencoded::byte_serialize(s.as_bytes())
        .collect::<String>()
        .replace('+', "%20")
}

pub fn method_url(name: &str) -> String {
    format!("/methods/{}", url_component(name))
}

#[cfg(test)]
mod tests {
    #[test]
    fn civil_time_formatting() {
        assert_eq!(super::fmt_time(0), "1970-01-01 00:00 UTC");
        assert_eq!(super::fmt_time(1_700_000_000), "2023-11-14 22:13 UTC");
    }
}

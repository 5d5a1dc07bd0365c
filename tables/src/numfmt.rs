//! Number formatting and escaping shared by the renderers.

use d3il_protocol::Source;

/// Formats a mean or std the way every format prints it (see the crate docs
/// for the precision policy).
pub fn number(x: f64, source: Source) -> String {
    let s = match source {
        // The paper printed three decimals, and more where three would have
        // shown 0.000 (e.g. `0.0009`); the JSON keeps exactly those digits, so
        // the shortest form with >= 3 decimals that reads back as the same
        // f64 reproduces the printed number.
        Source::Reported => (3..=12)
            .map(|d| format!("{x:.d$}"))
            .find(|s| s.parse::<f64>().ok() == Some(x))
            .unwrap_or_else(|| format!("{x}")),
        Source::Evaluated => return three_decimals(x),
    };
    no_negative_zero(s)
}

/// The one format of a number on the pages and of evaluated numbers in the
/// tables: three decimals (a tiny negative value prints as `0.000`).
pub fn three_decimals(x: f64) -> String {
    no_negative_zero(format!("{x:.3}"))
}

fn no_negative_zero(s: String) -> String {
    // A tiny negative value must not print as `-0.000`.
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// `mean ± std` over `n` training seeds, three decimals each: the spread only
/// where there is one (n >= 2); one seed prints its value alone. `—` for a
/// missing (non-finite) mean.
pub fn mean_std(mean: f64, std: f64, n: usize) -> String {
    if !mean.is_finite() {
        "—".into()
    } else if n >= 2 && std.is_finite() {
        format!("{} ± {}", three_decimals(mean), three_decimals(std))
    } else {
        three_decimals(mean)
    }
}

/// Rounds to the three printed decimals; bold decisions compare printed values
/// so that two numbers that look equal are treated as a tie.
pub fn printed_key(x: f64) -> i64 {
    (x * 1000.0).round() as i64
}

/// `10 %`-style percentage of a data fraction, without a trailing `.0`.
pub fn percent(fraction: f64) -> String {
    let p = fraction * 100.0;
    if (p - p.round()).abs() < 1e-9 {
        format!("{}", p.round() as i64)
    } else {
        format!("{p:.1}")
    }
}

/// Escapes text (method names come from submitters) for LaTeX text mode.
pub fn latex_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '\\' => out.push_str("\\textbackslash{}"),
            '{' | '}' | '&' | '%' | '$' | '#' | '_' => {
                out.push('\\');
                out.push(c);
            }
            '^' => out.push_str("\\textasciicircum{}"),
            '~' => out.push_str("\\textasciitilde{}"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// Escapes text for a Markdown table cell.
pub fn markdown_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '\\' | '|' | '*' | '_' | '`' | '[' | ']' => {
                out.push('\\');
                out.push(c);
            }
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csv::csv_field;

    #[test]
    fn reported_numbers_keep_the_papers_digits() {
        assert_eq!(number(0.42, Source::Reported), "0.420");
        assert_eq!(number(0.0009, Source::Reported), "0.0009");
        assert_eq!(number(0.0194, Source::Reported), "0.0194");
        assert_eq!(number(0.0, Source::Reported), "0.000");
        assert_eq!(number(0.95, Source::Reported), "0.950");
    }

    #[test]
    fn evaluated_numbers_have_three_decimals() {
        assert_eq!(number(0.72345, Source::Evaluated), "0.723");
        assert_eq!(number(-0.0001, Source::Evaluated), "0.000");
        assert_eq!(number(1.0, Source::Evaluated), "1.000");
    }

    #[test]
    fn spread_only_over_two_or_more_seeds() {
        assert_eq!(mean_std(0.5, 0.01944, 3), "0.500 ± 0.019");
        assert_eq!(mean_std(1.0, 0.0, 1), "1.000");
        assert_eq!(mean_std(0.25, 0.0, 0), "0.250");
        assert_eq!(mean_std(f64::NAN, 0.0, 2), "—");
        assert_eq!(mean_std(0.0009, 0.0, 2), "0.001 ± 0.000");
    }

    #[test]
    fn escapes() {
        assert_eq!(latex_escape("a_b&c%"), "a\\_b\\&c\\%");
        assert_eq!(markdown_escape("a|b*"), "a\\|b\\*");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
        assert_eq!(percent(0.1), "10");
        assert_eq!(percent(0.125), "12.5");
    }
}

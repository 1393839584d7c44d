//! Word error rate, for scoring transcripts against what was said. Both
//! sides are normalised the way speech-recognition evaluations usually are
//! (lower case, no punctuation, numbers as digits, units and honorifics in
//! one spelling) so that "move four metres" and "Move 4 m." score as equal.

fn canonical_word(word: &str) -> &str {
    match word {
        "meter" | "meters" | "metre" | "metres" => "m",
        "centimeter" | "centimeters" | "centimetre" | "centimetres" => "cm",
        "mr" => "mister",
        "mrs" => "missus",
        "dr" => "doctor",
        "okay" => "ok",
        _ => word,
    }
}

/// The words of `text` as they are compared: lower case, punctuation
/// dropped (hyphens split words), digits split from letters ("4m" → "4 m"),
/// number words up to ninety-nine as digits, units and titles canonical.
pub fn scoring_words(text: &str) -> Vec<String> {
    let mut spaced = String::with_capacity(text.len() + 8);
    let mut prev: Option<char> = None;
    for c in text.to_lowercase().chars() {
        let c = if c.is_alphanumeric() || c == '.' && prev.is_some_and(|p| p.is_ascii_digit()) { c } else { ' ' };
        if let Some(p) = prev
            && (p.is_ascii_digit() && c.is_alphabetic() || p.is_alphabetic() && c.is_ascii_digit())
        {
            spaced.push(' ');
        }
        spaced.push(c);
        prev = Some(c);
    }
    let raw: Vec<&str> = spaced.split_whitespace().map(|w| w.trim_end_matches('.')).filter(|w| !w.is_empty()).collect();
    let mut words = Vec::with_capacity(raw.len());
    let mut i = 0;
    while i < raw.len() {
        match vlnav_words::value(raw[i]) {
            Some(tens)
                if tens >= 20
                    && i + 1 < raw.len()
                    && vlnav_words::value(raw[i + 1]).is_some_and(|u| (1..10).contains(&u)) =>
            {
                words.push((tens + vlnav_words::value(raw[i + 1]).unwrap_or(0)).to_string());
                i += 2;
            }
            Some(n) => {
                words.push(n.to_string());
                i += 1;
            }
            None => {
                words.push(canonical_word(raw[i]).to_string());
                i += 1;
            }
        }
    }
    words
}

/// Word-level edit distance (substitutions + deletions + insertions).
pub fn word_edits(reference: &[String], hypothesis: &[String]) -> usize {
    let mut row: Vec<usize> = (0..=hypothesis.len()).collect();
    for (i, r) in reference.iter().enumerate() {
        let mut diag = row[0];
        row[0] = i + 1;
        for (j, h) in hypothesis.iter().enumerate() {
            let sub = diag + usize::from(r != h);
            diag = row[j + 1];
            row[j + 1] = sub.min(row[j] + 1).min(row[j + 1] + 1);
        }
    }
    row[hypothesis.len()]
}

/// Word error rate of `hypothesis` against `reference` after normalisation:
/// edits / reference words (0 for two empty texts, 1 for an empty reference
/// against a non-empty hypothesis).
pub fn word_error_rate(reference: &str, hypothesis: &str) -> f64 {
    let r = scoring_words(reference);
    let h = scoring_words(hypothesis);
    if r.is_empty() {
        return if h.is_empty() { 0.0 } else { 1.0 };
    }
    word_edits(&r, &h) as f64 / r.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &str) -> Vec<String> {
        s.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn normalisation_makes_spellings_comparable() {
        assert_eq!(scoring_words("Move 4m ahead!"), words("move 4 m ahead"));
        assert_eq!(scoring_words("move four metres ahead"), words("move 4 m ahead"));
        assert_eq!(scoring_words("Go ahead twenty-five meters."), words("go ahead 25 m"));
        assert_eq!(scoring_words("3.5 m, then Mr. David"), words("3.5 m then mister david"));
        assert_eq!(scoring_words("the statue (human)"), words("the statue human"));
    }

    #[test]
    fn edit_distance_counts_each_kind_of_error() {
        assert_eq!(word_edits(&words("a b c"), &words("a b c")), 0);
        assert_eq!(word_edits(&words("a b c"), &words("a x c")), 1);
        assert_eq!(word_edits(&words("a b c"), &words("a c")), 1);
        assert_eq!(word_edits(&words("a b c"), &words("a b c d e")), 2);
        assert_eq!(word_edits(&words("a b c"), &[]), 3);
    }

    #[test]
    fn rate_is_edits_over_reference_length() {
        assert_eq!(word_error_rate("Take left turn.", "take left turn"), 0.0);
        assert!((word_error_rate("take the left turn", "take a left turn") - 0.25).abs() < 1e-12);
        assert_eq!(word_error_rate("go", "stop now"), 2.0);
        assert_eq!(word_error_rate("", ""), 0.0);
        assert_eq!(word_error_rate("", "noise"), 1.0);
    }
}

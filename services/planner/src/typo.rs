//! Misspellings: a word outside a known vocabulary is corrected to the
//! closest vocabulary word within a small edit distance (optimal string
//! alignment: insert, delete, substitute, swap two neighbours), or left
//! alone when none is that close.
//!
//! Short words are where corrections go wrong ("red" is one letter from
//! "rad", "mind" from "find"), so words of three or four letters are only
//! corrected by a swap of neighbours ("teh" → "the") or a letter put back
//! ("fnd" → "find"); longer words by any one edit; targets of seven letters
//! or more by two ("bycicle" → "bicycle").

/// Edit distance with adjacent transpositions, stopping early above `max`.
pub fn distance(a: &str, b: &str, max: usize) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    if a.len().abs_diff(b.len()) > max {
        return max + 1;
    }
    let (n, m) = (a.len(), b.len());
    let mut d = vec![vec![0usize; m + 1]; n + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=n {
        let mut row_min = usize::MAX;
        for j in 1..=m {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut v = (d[i - 1][j] + 1).min(d[i][j - 1] + 1).min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                v = v.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = v;
            row_min = row_min.min(v);
        }
        if row_min > max {
            return max + 1;
        }
    }
    d[n][m]
}

fn is_swap(a: &str, b: &str) -> bool {
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    if a.len() != b.len() {
        return false;
    }
    let diff: Vec<usize> = (0..a.len()).filter(|&i| a[i] != b[i]).collect();
    diff.len() == 2 && diff[1] == diff[0] + 1 && a[diff[0]] == b[diff[1]] && a[diff[1]] == b[diff[0]]
}

/// Whether `candidate` is an acceptable correction of `word` (see the module
/// documentation); `long_reach` allows two edits for words of 7+ letters.
fn acceptable(word: &str, candidate: &str, long_reach: bool) -> bool {
    let n = word.chars().count();
    if n < 3 {
        return false;
    }
    if n <= 4 {
        return is_swap(word, candidate)
            || (candidate.chars().count() == n + 1 && distance(word, candidate, 1) == 1 && n >= 3);
    }
    let max = if long_reach && n >= 7 { 2 } else { 1 };
    distance(word, candidate, max) <= max
}

/// The vocabulary word `word` is a misspelling of: the closest acceptable
/// one, the first in vocabulary order on a tie ("meteres" is one edit from
/// both "meters" and "metres"). `word` itself in the vocabulary, or not
/// alphabetic: `None`.
pub fn correct<'a>(word: &str, vocabulary: &[&'a str], long_reach: bool) -> Option<&'a str> {
    if !word.chars().all(|c| c.is_ascii_lowercase()) || vocabulary.contains(&word) {
        return None;
    }
    let mut best: Option<(usize, &'a str)> = None;
    for &v in vocabulary {
        if !acceptable(word, v, long_reach) {
            continue;
        }
        let d = distance(word, v, 2);
        if best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, v));
        }
    }
    best.map(|(_, v)| v)
}

/// Every vocabulary word at the smallest acceptable distance from `word`
/// (several when two words are equally near: "cas" → "car", "cat").
pub fn candidates<'a>(word: &str, vocabulary: &[&'a str], long_reach: bool) -> Vec<&'a str> {
    if !word.chars().all(|c| c.is_ascii_lowercase()) || vocabulary.contains(&word) {
        return Vec::new();
    }
    let mut best: Vec<(usize, &'a str)> = Vec::new();
    for &v in vocabulary {
        if !acceptable(word, v, long_reach) {
            continue;
        }
        let d = distance(word, v, 2);
        match best.first() {
            Some((bd, _)) if d > *bd => {}
            Some((bd, _)) if d < *bd => best = vec![(d, v)],
            _ => best.push((d, v)),
        }
    }
    best.into_iter().map(|(_, v)| v).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const WORDS: &[&str] = &["turn", "left", "right", "the", "find", "forward", "move", "follow", "meters", "chair"];

    #[test]
    fn corrects_common_slips() {
        for (typo, want) in [
            ("trun", "turn"),
            ("lfet", "left"),
            ("rigth", "right"),
            ("teh", "the"),
            ("fnd", "find"),
            ("forwrad", "forward"),
            ("mvoe", "move"),
            ("folow", "follow"),
            ("meteres", "meters"),
            ("chiar", "chair"),
        ] {
            assert_eq!(correct(typo, WORDS, false), Some(want), "{typo}");
        }
    }

    #[test]
    fn leaves_short_words_and_known_words_alone() {
        assert_eq!(correct("mind", WORDS, false), None, "a substitution in a short word is another word");
        assert_eq!(correct("red", &["rad"], false), None);
        assert_eq!(correct("turn", WORDS, false), None);
        assert_eq!(correct("kitchen", WORDS, true), None);
        assert_eq!(correct("bycicle", &["bicycle"], true), Some("bicycle"));
        assert_eq!(correct("bycicle", &["bicycle"], false), None);
    }

    #[test]
    fn distance_counts_swaps_as_one_edit() {
        assert_eq!(distance("abcd", "abdc", 3), 1);
        assert_eq!(distance("kitten", "sitting", 5), 3);
        assert_eq!(distance("a", "abcdef", 2), 3);
    }
}

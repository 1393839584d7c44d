//! English number words: one list for the services that read what people
//! say. The planner's parser reads "two metres" (`services/planner/src/htn.rs`),
//! and the ingress's word error rate scores "four" and "4" as one word
//! (`services/ingress/src/wer.rs`).

/// The words for 0 to 19; the index is the value.
pub const UNITS: [&str; 20] = [
    "zero",
    "one",
    "two",
    "three",
    "four",
    "five",
    "six",
    "seven",
    "eight",
    "nine",
    "ten",
    "eleven",
    "twelve",
    "thirteen",
    "fourteen",
    "fifteen",
    "sixteen",
    "seventeen",
    "eighteen",
    "nineteen",
];

/// The words for 20 to 90 in tens; index `i` is `20 + 10 i`.
pub const TENS: [&str; 8] = ["twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety"];

/// The value of one number word: 0 to 19, or a multiple of ten from 20 to 90.
pub fn value(word: &str) -> Option<u32> {
    if let Some(i) = UNITS.iter().position(|u| *u == word) {
        return Some(i as u32);
    }
    TENS.iter().position(|t| *t == word).map(|i| 20 + 10 * i as u32)
}

/// Every number word [`value`] reads.
pub fn all() -> impl Iterator<Item = &'static str> {
    UNITS.into_iter().chain(TENS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_and_tens_read_as_their_values() {
        assert_eq!(value("zero"), Some(0));
        assert_eq!(value("nineteen"), Some(19));
        assert_eq!(value("twenty"), Some(20));
        assert_eq!(value("ninety"), Some(90));
        assert_eq!(value("hundred"), None);
        assert_eq!(value("Two"), None, "callers lower-case first");
        assert_eq!(all().count(), 28);
        assert!(all().all(|w| value(w).is_some()));
    }
}

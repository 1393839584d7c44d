//! Grounding a spoken target phrase to a COCO-80 class id: exact names and a
//! synonyms table first (deterministic, microseconds), then semantic
//! similarity with all-MiniLM-L6-v2 against every class name and synonym.
//! Below [`DEFAULT_THRESHOLD`] the phrase is not grounded and the planner
//! asks instead of guessing.

use vlnav_proto::coco;

use crate::minilm::{EmbedError, MiniLm, cosine};

/// Cosine similarity a phrase needs to the closest class name or synonym
/// for semantic grounding. Tuned on the phrases in `tests/grounding.rs`:
/// paraphrases of COCO objects outside the synonyms table score 0.75–0.96
/// (lowest: "racing bicycle" 0.755 to "bicycle"); places and landmarks that no
/// COCO class covers score at most 0.62 ("parking lot" to "parking meter",
/// "window" 0.61 to "screen", "kitchen" 0.61 to "oven"). 0.65 sits between.
pub const DEFAULT_THRESHOLD: f32 = 0.65;

/// Similarity the head noun (last word) of a multi-word phrase needs, on its
/// own, to the class the whole phrase grounds to semantically. A phrase is
/// about its head noun: "couch cushion" (cushion ~ sofa 0.63) is about a
/// couch, but "visitor care" (care ~ person < 0.4) is not about a person
/// just because "visitor" is — a mishearing of "visitor chair" must ask,
/// not send the robot to a person.
pub const HEAD_THRESHOLD: f32 = 0.45;

/// Head nouns that say a thing depicts what the other words name:
/// "elephant statue" looks like an elephant.
pub const DEPICTIONS: &[&str] = &[
    "statue",
    "statues",
    "sculpture",
    "sculptures",
    "figure",
    "figures",
    "figurine",
    "figurines",
    "model",
    "models",
    "picture",
    "pictures",
    "painting",
    "paintings",
    "poster",
    "posters",
    "photo",
    "photos",
    "image",
    "images",
    "drawing",
    "drawings",
    "mural",
    "cutout",
    "cutouts",
    "replica",
    "replicas",
    "toy",
    "toys",
    "doll",
    "dolls",
];

/// Phrases (lower case) that name a COCO class without being its name.
pub const SYNONYMS: &[(&str, &str)] = &[
    // people
    ("human", "person"),
    ("people", "person"),
    ("man", "person"),
    ("woman", "person"),
    ("men", "person"),
    ("women", "person"),
    ("guy", "person"),
    ("lady", "person"),
    ("gentleman", "person"),
    ("boy", "person"),
    ("girl", "person"),
    ("child", "person"),
    ("kid", "person"),
    ("visitor", "person"),
    ("pedestrian", "person"),
    ("someone", "person"),
    ("somebody", "person"),
    ("worker", "person"),
    ("guest", "person"),
    ("me", "person"),
    ("standing person", "person"),
    ("mannequin", "person"),
    ("friend", "person"),
    ("colleague", "person"),
    ("user", "person"),
    // vehicles
    ("bike", "bicycle"),
    ("cycle", "bicycle"),
    ("motorbike", "motorcycle"),
    ("motor bike", "motorcycle"),
    ("scooter", "motorcycle"),
    ("automobile", "car"),
    ("vehicle", "car"),
    ("plane", "airplane"),
    ("aeroplane", "airplane"),
    ("lorry", "truck"),
    ("ship", "boat"),
    ("traffic signal", "traffic light"),
    ("hydrant", "fire hydrant"),
    // furniture and household
    ("visitor chair", "chair"),
    ("office chair", "chair"),
    ("armchair", "chair"),
    ("stool", "chair"),
    ("seat", "chair"),
    ("sofa", "couch"),
    ("settee", "couch"),
    ("loveseat", "couch"),
    ("table", "dining table"),
    ("desk", "dining table"),
    ("plant", "potted plant"),
    ("houseplant", "potted plant"),
    ("flower pot", "potted plant"),
    ("pot plant", "potted plant"),
    ("television", "tv"),
    ("tv set", "tv"),
    ("monitor", "tv"),
    ("screen", "tv"),
    ("telly", "tv"),
    ("computer", "laptop"),
    ("fridge", "refrigerator"),
    ("phone", "cell phone"),
    ("mobile", "cell phone"),
    ("mobile phone", "cell phone"),
    ("smartphone", "cell phone"),
    ("cellphone", "cell phone"),
    ("remote control", "remote"),
    ("mug", "cup"),
    ("coffee cup", "cup"),
    ("glass", "wine glass"),
    ("water bottle", "bottle"),
    ("teddy", "teddy bear"),
    ("stuffed bear", "teddy bear"),
    ("stuffed animal", "teddy bear"),
    ("ball", "sports ball"),
    ("football", "sports ball"),
    ("soccer ball", "sports ball"),
    ("bag", "handbag"),
    ("purse", "handbag"),
    ("rucksack", "backpack"),
    ("luggage", "suitcase"),
    ("hair dryer", "hair drier"),
    ("bathtub", "sink"),
    ("washbasin", "sink"),
    ("microwave oven", "microwave"),
    ("stove", "oven"),
    ("timepiece", "clock"),
    ("doughnut", "donut"),
    // animals
    ("puppy", "dog"),
    ("doggy", "dog"),
    ("kitten", "cat"),
    ("kitty", "cat"),
    ("pony", "horse"),
    ("lamb", "sheep"),
    // everyday names: people
    ("children", "person"),
    ("baby", "person"),
    ("toddler", "person"),
    ("teenager", "person"),
    ("adult", "person"),
    ("persons", "person"),
    ("student", "person"),
    ("teacher", "person"),
    ("doctor", "person"),
    ("nurse", "person"),
    ("guard", "person"),
    ("security guard", "person"),
    ("officer", "person"),
    ("policeman", "person"),
    ("waiter", "person"),
    ("customer", "person"),
    ("stranger", "person"),
    ("mom", "person"),
    ("mum", "person"),
    ("dad", "person"),
    ("mother", "person"),
    ("father", "person"),
    ("grandma", "person"),
    ("grandpa", "person"),
    ("boss", "person"),
    ("dude", "person"),
    ("fellow", "person"),
    // vehicles and street
    ("taxi", "car"),
    ("cab", "car"),
    ("suv", "car"),
    ("pickup truck", "truck"),
    ("jet", "airplane"),
    ("aircraft", "airplane"),
    ("canoe", "boat"),
    ("kayak", "boat"),
    ("stoplight", "traffic light"),
    ("traffic lights", "traffic light"),
    ("coach bus", "bus"),
    // household
    ("freezer", "refrigerator"),
    ("tv remote", "remote"),
    ("clicker", "remote"),
    ("telephone", "cell phone"),
    ("iphone", "cell phone"),
    ("teacup", "cup"),
    ("wineglass", "wine glass"),
    ("hairdryer", "hair drier"),
    ("blow dryer", "hair drier"),
    ("blowdryer", "hair drier"),
    ("plushie", "teddy bear"),
    ("soft toy", "teddy bear"),
    ("brolly", "umbrella"),
    ("schoolbag", "backpack"),
    ("knapsack", "backpack"),
    ("necktie", "tie"),
    ("racket", "tennis racket"),
    ("racquet", "tennis racket"),
    ("tennis racquet", "tennis racket"),
    ("flying disc", "frisbee"),
    ("basketball", "sports ball"),
    ("tennis ball", "sports ball"),
    ("volleyball", "sports ball"),
    ("hotdog", "hot dog"),
    ("cupcake", "cake"),
    ("notebook computer", "laptop"),
    ("pc", "laptop"),
    ("loo", "toilet"),
    ("alarm clock", "clock"),
    ("wall clock", "clock"),
    ("flower vase", "vase"),
    ("flowers", "potted plant"),
];

/// Where a grounding came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Via {
    /// The phrase (or its head noun) is a class name or in [`SYNONYMS`].
    Lexical(String),
    /// MiniLM similarity to the given class name or synonym.
    Semantic { matched: String, score: f32 },
}

#[derive(Clone, Debug, PartialEq)]
pub struct Grounding {
    pub class_id: i32,
    pub via: Via,
}

/// A phrase that could not be grounded, with the nearest classes to offer.
#[derive(Clone, Debug, PartialEq)]
pub struct Ungrounded {
    pub phrase: String,
    pub suggestions: Vec<String>,
}

struct Entry {
    phrase: String,
    class_id: i32,
    embedding: Vec<f32>,
}

pub struct Grounder {
    minilm: Option<MiniLm>,
    entries: Vec<Entry>,
    threshold: f32,
}

impl Grounder {
    /// Lexical grounding with semantic similarity on top; embeds every class
    /// name and synonym once.
    pub fn with_minilm(minilm: MiniLm, threshold: f32) -> Result<Grounder, EmbedError> {
        let mut entries = Vec::with_capacity(coco::CLASSES.len() + SYNONYMS.len());
        let phrases = coco::CLASSES.iter().enumerate().map(|(i, c)| (c.to_string(), i as i32)).chain(
            SYNONYMS
                .iter()
                .filter(|(s, _)| !matches!(*s, "me"))
                .map(|(s, c)| (s.to_string(), coco::id(c).expect("synonyms map to COCO names"))),
        );
        for (phrase, class_id) in phrases {
            let embedding = minilm.embed(&phrase)?;
            entries.push(Entry { phrase, class_id, embedding });
        }
        Ok(Grounder { minilm: Some(minilm), entries, threshold })
    }

    /// Class names and the synonyms table only (no semantic stage).
    pub fn lexical_only() -> Grounder {
        Grounder { minilm: None, entries: Vec::new(), threshold: DEFAULT_THRESHOLD }
    }

    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    pub fn has_semantic(&self) -> bool {
        self.minilm.is_some()
    }

    /// Grounds a target phrase ("visitor chair", "statue (human)", "sofa").
    pub fn ground(&self, phrase: &str) -> Result<Grounding, Ungrounded> {
        let phrase = phrase.trim().to_lowercase();
        // "statue (elephant)": the parenthesis says what the thing depicts.
        if let (Some(open), Some(close)) = (phrase.find('('), phrase.rfind(')'))
            && open < close
        {
            let inner = phrase[open + 1..close].trim();
            if let Some(g) = lexical(inner) {
                return Ok(g);
            }
            let outer = format!("{} {}", phrase[..open].trim(), phrase[close + 1..].trim());
            if let Some(g) = lexical(outer.trim()) {
                return Ok(g);
            }
        }
        if let Some(g) = lexical(&phrase) {
            return Ok(g);
        }
        match self.semantic(&phrase) {
            Some((best, score, _)) if score >= self.threshold && self.head_agrees(&phrase, best.class_id) => {
                Ok(Grounding { class_id: best.class_id, via: Via::Semantic { matched: best.phrase.clone(), score } })
            }
            Some((_, _, suggestions)) => Err(Ungrounded { phrase, suggestions }),
            None => Err(Ungrounded { phrase, suggestions: Vec::new() }),
        }
    }

    /// Whether the head noun of `phrase` is about `class_id` too: a single
    /// word, a head noun that names the class itself, or one whose own
    /// similarity to the class reaches [`HEAD_THRESHOLD`].
    fn head_agrees(&self, phrase: &str, class_id: i32) -> bool {
        let words: Vec<&str> = phrase.split_whitespace().collect();
        let Some(head) = words.last().filter(|_| words.len() > 1) else { return true };
        if let Some(g) = lexical_exact(head) {
            return g.class_id == class_id;
        }
        self.class_score(head, class_id).is_some_and(|s| s >= HEAD_THRESHOLD)
    }

    /// Highest similarity of `phrase` to a name or synonym of `class_id`.
    pub fn class_score(&self, phrase: &str, class_id: i32) -> Option<f32> {
        let q = self.minilm.as_ref()?.embed(phrase).ok()?;
        self.entries.iter().filter(|e| e.class_id == class_id).map(|e| cosine(&q, &e.embedding)).max_by(f32::total_cmp)
    }

    /// The nearest entry, its score and the three nearest distinct class names.
    fn semantic(&self, phrase: &str) -> Option<(&Entry, f32, Vec<String>)> {
        let minilm = self.minilm.as_ref()?;
        let q = minilm.embed(phrase).ok()?;
        let mut scored: Vec<(f32, &Entry)> = self.entries.iter().map(|e| (cosine(&q, &e.embedding), e)).collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut suggestions: Vec<String> = Vec::new();
        for (_, e) in &scored {
            let name = coco::CLASSES[e.class_id as usize].to_string();
            if !suggestions.contains(&name) {
                suggestions.push(name);
            }
            if suggestions.len() == 3 {
                break;
            }
        }
        let (score, best) = scored.first().copied()?;
        Some((best, score, suggestions))
    }

    /// Similarity of `phrase` to its closest class name or synonym (for tuning).
    pub fn best_score(&self, phrase: &str) -> Option<(String, f32)> {
        self.semantic(&phrase.to_lowercase()).map(|(e, s, _)| (e.phrase.clone(), s))
    }
}

/// Every word of every class name and synonym ("teddy", "bear", "sofa", …),
/// the vocabulary misspelt targets are corrected to.
pub fn class_words() -> &'static [&'static str] {
    static WORDS: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    WORDS.get_or_init(|| {
        let mut v: Vec<&'static str> = coco::CLASSES
            .iter()
            .copied()
            .chain(SYNONYMS.iter().map(|(s, _)| *s))
            .flat_map(str::split_whitespace)
            .filter(|w| w.len() > 2)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    })
}

/// A class name or synonym, as is or in the singular.
fn lexical_exact(word: &str) -> Option<Grounding> {
    let exact = |p: &str| -> Option<Grounding> {
        let name = coco::id(p).map(|_| p).or_else(|| SYNONYMS.iter().find(|(s, _)| *s == p).map(|(_, c)| *c))?;
        Some(Grounding { class_id: coco::id(name)?, via: Via::Lexical(p.to_string()) })
    };
    exact(word).or_else(|| exact(&singular(word)))
}

/// Exact class name or synonym, for the phrase, its singular, its head noun
/// (last word: "red chair" → chair), or — when the head noun is a depiction
/// ("elephant statue", "human statue") — a word before it naming a class.
/// A modifier alone does not ground a phrase whose head noun is something
/// else ("visitor care" is not a person).
pub fn lexical(phrase: &str) -> Option<Grounding> {
    let exact = |p: &str| -> Option<Grounding> {
        let name = coco::id(p).map(|_| p).or_else(|| SYNONYMS.iter().find(|(s, _)| *s == p).map(|(_, c)| *c))?;
        Some(Grounding { class_id: coco::id(name)?, via: Via::Lexical(p.to_string()) })
    };
    let words: Vec<&str> = phrase.split_whitespace().collect();
    if words.is_empty() {
        return None;
    }
    let joined = words.join(" ");
    exact(&joined)
        .or_else(|| exact(&singular(&joined)))
        // The last two words ("the red office chair" → "office chair"), then the head noun.
        .or_else(|| {
            (words.len() > 2)
                .then(|| words[words.len() - 2..].join(" "))
                .and_then(|p| exact(&p).or_else(|| exact(&singular(&p))))
        })
        .or_else(|| exact(words[words.len() - 1]).or_else(|| exact(&singular(words[words.len() - 1]))))
        .or_else(|| {
            DEPICTIONS
                .contains(&words[words.len() - 1])
                .then(|| words.iter().rev().find_map(|w| exact(w).or_else(|| exact(&singular(w)))))
                .flatten()
        })
}

fn singular(w: &str) -> String {
    if let Some(stem) = w.strip_suffix("ies") {
        format!("{stem}y")
    } else if w.ends_with("ches") || w.ends_with("shes") || w.ends_with("sses") || w.ends_with("xes") {
        w[..w.len() - 2].to_string()
    } else if let Some(stem) = w.strip_suffix('s')
        && !w.ends_with("ss")
    {
        stem.to_string()
    } else {
        w.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(p: &str) -> Option<i32> {
        Grounder::lexical_only().ground(p).ok().map(|g| g.class_id)
    }

    #[test]
    fn grounds_names_synonyms_heads_and_parentheses() {
        assert_eq!(id("chair"), Some(56));
        assert_eq!(id("visitor chair"), Some(56));
        assert_eq!(id("the red chairs"), Some(56));
        assert_eq!(id("sofa"), Some(57));
        assert_eq!(id("water bottle"), Some(39));
        assert_eq!(id("TV"), Some(62));
        assert_eq!(id("elephant statue"), Some(20));
        assert_eq!(id("statue (human)"), Some(0));
        assert_eq!(id("statue (Elephant)"), Some(20));
        assert_eq!(id("standing person"), Some(0));
        assert_eq!(id("benches"), Some(13));
        assert_eq!(id("potted plants"), Some(58));
    }

    #[test]
    fn leaves_unknown_phrases_ungrounded_without_the_semantic_stage() {
        assert_eq!(id("pharmacy"), None);
        assert_eq!(id("statue"), None);
        assert_eq!(id(""), None);
        // A modifier naming a class does not ground another head noun.
        assert_eq!(id("visitor care"), None);
        assert_eq!(id("visitor character each close"), None);
    }

    #[test]
    fn every_synonym_maps_to_a_coco_class() {
        for (s, c) in SYNONYMS {
            assert!(coco::id(c).is_some(), "{s} → {c}");
        }
    }
}

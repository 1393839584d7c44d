//! A model's own classes and how they are reported: every box the service
//! returns carries a COCO-80 class id (what FIND and FOLLOW ask for) and the
//! name of the class the model saw. A fine-tuned YOLOv8 brings its own classes
//! (e.g. `{0: Normal, 1: Fall}`, both people); a class-names file says what they
//! are called and, optionally, which COCO class each one is.
//!
//! The file is YAML or JSON as ultralytics writes class names (a dataset's
//! `data.yaml`, or an export's `names` metadata):
//!
//! ```yaml
//! names:            # or `names: [Normal, Fall]`, or `{0: Normal, 1: Fall}`
//!   0: Normal
//!   1: Fall
//! coco:             # optional: model class → COCO id or COCO name
//!   0: person
//!   1: 0
//! ```
//!
//! A class without a `coco` entry whose name is a COCO class name (any case)
//! is that class; any other class is reported with class id −1 (a request's
//! `class_ids` never selects it) and its name in `label`.

use std::path::{Path, PathBuf};

use yaml_rust::{Yaml, YamlLoader};

use crate::detection::{DetectFilter, Detection};

/// A detection as the service reports it: COCO class id (−1 when the model's
/// class has no COCO counterpart) and the model's class name.
#[derive(Clone, Debug, PartialEq)]
pub struct Labeled {
    pub detection: Detection,
    pub label: String,
}

impl Labeled {
    /// A detection whose class id already is a COCO id, labelled with the COCO name.
    pub fn coco(detection: Detection) -> Self {
        Self { detection, label: vlnav_proto::coco::name(detection.class_id).unwrap_or_default().to_string() }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ClassMapError {
    #[error("{path}: {msg}")]
    Invalid { path: String, msg: String },
    #[error("cannot read the class-names file {path}: {msg}")]
    Read { path: String, msg: String },
}

/// A model's classes: names and COCO ids, indexed by the model's class index.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassMap {
    names: Vec<String>,
    coco: Vec<Option<i32>>,
}

impl ClassMap {
    /// The COCO-80 classes themselves (a model trained on COCO).
    pub fn coco80() -> Self {
        let names: Vec<String> = vlnav_proto::coco::CLASSES.iter().map(|s| s.to_string()).collect();
        let coco = (0..names.len() as i32).map(Some).collect();
        Self { names, coco }
    }

    /// Reads a class-names file (YAML or JSON).
    pub fn load(path: &Path) -> Result<Self, ClassMapError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ClassMapError::Read { path: path.display().to_string(), msg: e.to_string() })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses a class-names document; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, ClassMapError> {
        let err = |msg: String| ClassMapError::Invalid { path: origin.to_string(), msg };
        let docs = YamlLoader::load_from_str(text).map_err(|e| err(format!("not YAML or JSON: {e}")))?;
        let doc = docs.into_iter().next().ok_or_else(|| err("the file is empty".into()))?;
        // `names:` (a dataset YAML), else the document itself is the names (`{0: a, 1: b}` or `[a, b]`).
        let (names_node, coco_node) = match &doc {
            Yaml::Hash(h) if h.contains_key(&Yaml::String("names".into())) => {
                (doc["names"].clone(), doc["coco"].clone())
            }
            Yaml::Hash(h) if !h.keys().all(|k| index(k).is_some()) => (Yaml::BadValue, Yaml::BadValue),
            _ => (doc.clone(), Yaml::BadValue),
        };
        let names: Vec<String> = match &names_node {
            Yaml::Array(items) => items
                .iter()
                .enumerate()
                .map(|(i, v)| scalar(v).ok_or_else(|| err(format!("names[{i}] is not a name"))))
                .collect::<Result<_, _>>()?,
            Yaml::Hash(h) => {
                let mut pairs = Vec::with_capacity(h.len());
                for (k, v) in h {
                    let i = index(k).ok_or_else(|| err(format!("names: key {k:?} is not a class index")))?;
                    let name = scalar(v).ok_or_else(|| err(format!("names: class {i} has no name")))?;
                    pairs.push((i, name));
                }
                pairs.sort_by_key(|p| p.0);
                for (expect, (i, _)) in pairs.iter().enumerate() {
                    if *i != expect {
                        return Err(err(format!("names: class indices must be 0..{} without gaps", pairs.len())));
                    }
                }
                pairs.into_iter().map(|p| p.1).collect()
            }
            _ => return Err(err("no `names:` list or mapping of class index → name".into())),
        };
        if names.is_empty() {
            return Err(err("names: no classes".into()));
        }
        if let Some(nc) = doc["nc"].as_i64()
            && nc as usize != names.len()
        {
            return Err(err(format!("nc is {nc}, but names lists {} classes", names.len())));
        }
        let mut coco: Vec<Option<i32>> = names.iter().map(|n| coco_id_of_name(n)).collect();
        match &coco_node {
            Yaml::BadValue | Yaml::Null => {}
            Yaml::Hash(h) => {
                for (k, v) in h {
                    let i = index(k)
                        .filter(|&i| i < names.len())
                        .or_else(|| scalar(k).and_then(|n| names.iter().position(|m| *m == n)))
                        .ok_or_else(|| err(format!("coco: {k:?} is not one of the {} classes", names.len())))?;
                    coco[i] =
                        match v {
                            Yaml::Null => None,
                            Yaml::Integer(id) if vlnav_proto::coco::name(*id as i32).is_some() => Some(*id as i32),
                            _ => Some(scalar(v).and_then(|n| coco_id_of_name(&n)).ok_or_else(|| {
                                err(format!("coco: {v:?} (for {}) is not a COCO-80 class", names[i]))
                            })?),
                        };
                }
            }
            other => return Err(err(format!("coco: expected a mapping of class → COCO class, got {other:?}"))),
        }
        Ok(Self { names, coco })
    }

    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The model's name of class `i`.
    pub fn name(&self, i: usize) -> &str {
        self.names.get(i).map(String::as_str).unwrap_or("?")
    }

    /// The COCO id model class `i` is reported as.
    pub fn coco_id(&self, i: usize) -> Option<i32> {
        self.coco.get(i).copied().flatten()
    }

    /// A request's filter (COCO ids) in the model's class indices.
    pub fn model_filter(&self, filter: &DetectFilter) -> DetectFilter {
        if filter.class_ids.is_empty() {
            return filter.clone();
        }
        let mut class_ids: Vec<i32> = (0..self.len())
            .filter(|&i| self.coco_id(i).is_some_and(|c| filter.class_ids.contains(&c)))
            .map(|i| i as i32)
            .collect();
        if class_ids.is_empty() {
            // No model class is any of the requested ones; −1 is no model class, so nothing passes.
            class_ids.push(-1);
        }
        DetectFilter { class_ids, min_score: filter.min_score }
    }

    /// A detection in model class indices as the service reports it.
    pub fn report(&self, d: Detection) -> Labeled {
        let i = d.class_id as usize;
        Labeled {
            detection: Detection { class_id: self.coco_id(i).unwrap_or(-1), ..d },
            label: self.name(i).to_string(),
        }
    }

    /// The class-names file next to a weights file: `x.safetensors` → `x.names.yaml`, else `x.names.json`.
    pub fn file_next_to(weights: &Path) -> Option<PathBuf> {
        let stem = weights.file_stem()?.to_str()?;
        ["yaml", "yml", "json"]
            .iter()
            .map(|ext| weights.with_file_name(format!("{stem}.names.{ext}")))
            .find(|p| p.is_file())
    }
}

/// A YAML scalar as text (names like `yes` or `1` parse as other types).
fn scalar(v: &Yaml) -> Option<String> {
    match v {
        Yaml::String(s) => Some(s.clone()),
        Yaml::Integer(i) => Some(i.to_string()),
        Yaml::Real(r) => Some(r.clone()),
        Yaml::Boolean(b) => Some(b.to_string()),
        _ => None,
    }
}

/// A class index key: `0` in YAML, `"0"` in JSON.
fn index(k: &Yaml) -> Option<usize> {
    match k {
        Yaml::Integer(i) if *i >= 0 => Some(*i as usize),
        Yaml::String(s) => s.parse().ok(),
        _ => None,
    }
}

fn coco_id_of_name(name: &str) -> Option<i32> {
    let n = name.trim();
    vlnav_proto::coco::CLASSES.iter().position(|c| c.eq_ignore_ascii_case(n)).map(|i| i as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(class_id: i32) -> Detection {
        Detection { x_min: 0.0, y_min: 0.0, x_max: 1.0, y_max: 1.0, class_id, score: 0.9 }
    }

    #[test]
    fn ultralytics_yaml_with_a_coco_mapping() {
        let m = ClassMap::parse("names:\n  0: Normal\n  1: Fall\ncoco:\n  0: person\n  1: 0\n", "t.yaml").unwrap();
        assert_eq!(m.names(), ["Normal", "Fall"]);
        assert_eq!((m.coco_id(0), m.coco_id(1)), (Some(0), Some(0)));
        assert_eq!(m.report(det(1)), Labeled { detection: det(0), label: "Fall".into() });
        // FIND person selects both model classes; FIND chair selects none.
        let f = |ids: Vec<i32>| DetectFilter { class_ids: ids, min_score: 0.4 };
        assert_eq!(m.model_filter(&f(vec![0])).class_ids, vec![0, 1]);
        assert_eq!(m.model_filter(&f(vec![56])).class_ids, vec![-1]);
        assert!(m.model_filter(&f(vec![])).class_ids.is_empty());
    }

    #[test]
    fn flow_lists_json_and_names_that_are_coco_classes() {
        let flow = ClassMap::parse("names: {0: 'Normal', 1: 'Fall'}", "meta").unwrap();
        assert_eq!(flow.names(), ["Normal", "Fall"]);
        assert_eq!(flow.coco_id(0), None);
        assert_eq!(flow.report(det(0)).detection.class_id, -1);
        let list = ClassMap::parse("nc: 3\nnames: [Person, forklift, Chair]\n", "data.yaml").unwrap();
        assert_eq!((list.coco_id(0), list.coco_id(1), list.coco_id(2)), (Some(0), None, Some(56)));
        let json = ClassMap::parse(r#"{"names": {"0": "car", "1": "no"}, "coco": {"no": null}}"#, "n.json").unwrap();
        assert_eq!(json.names(), ["car", "no"]);
        assert_eq!((json.coco_id(0), json.coco_id(1)), (Some(2), None));
        let bare = ClassMap::parse(r#"{"0": "dog"}"#, "n.json").unwrap();
        assert_eq!(bare.coco_id(0), Some(16));
        assert_eq!(ClassMap::coco80().len(), 80);
    }

    #[test]
    fn bad_files_say_what_is_wrong() {
        let e = |t: &str| ClassMap::parse(t, "x.yaml").unwrap_err().to_string();
        assert!(e("names: {0: a, 2: b}").contains("without gaps"));
        assert!(e("nc: 3\nnames: [a, b]").contains("nc is 3"));
        assert!(e("names: [a]\ncoco: {0: giraffe-ish}").contains("not a COCO-80 class"));
        assert!(e("names: [a]\ncoco: {5: person}").contains("not one of the 1 classes"));
        assert!(e("classes: 3").contains("no `names:`"));
        assert!(e("names: [a").contains("not YAML or JSON"));
        assert!(e("").contains("empty"));
        let missing = ClassMap::load(Path::new("/nonexistent/x.names.yaml")).unwrap_err().to_string();
        assert!(missing.contains("/nonexistent/x.names.yaml"), "{missing}");
    }
}

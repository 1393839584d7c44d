//! The gallery of named people: L2-normalised embeddings per name, matched by
//! cosine similarity, persisted as one JSON file written atomically (a
//! temporary file in the same directory, fsynced, then renamed over the old one).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Embeddings kept per person; enrolling more drops the oldest.
pub const MAX_EMBEDDINGS_PER_PERSON: usize = 64;

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Gallery {
    /// The model the embeddings came from (embeddings of different models are
    /// not comparable); `sim` for the simulation backend, which stores none.
    pub model: String,
    pub dim: usize,
    pub people: BTreeMap<String, Person>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Person {
    /// Images enrolled in total (the simulation backend stores no embeddings).
    pub images: u32,
    pub embeddings: Vec<Vec<f32>>,
}

/// A person's best score against one query.
#[derive(Clone, Debug, PartialEq)]
pub struct Match {
    pub name: String,
    pub similarity: f32,
}

#[derive(Debug, thiserror::Error)]
pub enum GalleryError {
    #[error("cannot read the gallery {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("the gallery {path} is corrupt: {source}")]
    Corrupt { path: PathBuf, source: serde_json::Error },
    #[error(
        "the gallery {path} holds {found} embeddings but this service runs {expected}; use another data dir or remove the file"
    )]
    WrongModel { path: PathBuf, found: String, expected: String },
    #[error("cannot write the gallery {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

/// Cosine similarity of two L2-normalised vectors.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl Gallery {
    pub fn new(model: &str, dim: usize) -> Self {
        Self { model: model.to_string(), dim, people: BTreeMap::new() }
    }

    pub fn is_empty(&self) -> bool {
        self.people.is_empty()
    }

    pub fn contains(&self, name: &str) -> bool {
        self.people.contains_key(name)
    }

    /// Adds `images` enrolled images with their `embeddings` (possibly none)
    /// to `name`, creating it; returns the person's embedding count.
    pub fn enroll(&mut self, name: &str, images: u32, embeddings: Vec<Vec<f32>>) -> usize {
        let person = self.people.entry(name.to_string()).or_default();
        person.images += images;
        person.embeddings.extend(embeddings);
        let excess = person.embeddings.len().saturating_sub(MAX_EMBEDDINGS_PER_PERSON);
        person.embeddings.drain(..excess);
        person.embeddings.len()
    }

    pub fn remove(&mut self, name: &str) -> bool {
        self.people.remove(name).is_some()
    }

    /// (name, stored count) for every person, sorted by name. The count is the
    /// embeddings kept, or the images enrolled when none are stored.
    pub fn list(&self) -> Vec<(String, u32)> {
        self.people
            .iter()
            .map(|(n, p)| (n.clone(), if p.embeddings.is_empty() { p.images } else { p.embeddings.len() as u32 }))
            .collect()
    }

    /// The person whose closest stored embedding is most similar to `query`
    /// (restricted to `only` when given). `None` if nobody has embeddings.
    pub fn best_match(&self, query: &[f32], only: Option<&str>) -> Option<Match> {
        self.people
            .iter()
            .filter(|(n, _)| only.is_none_or(|o| o == n.as_str()))
            .filter_map(|(n, p)| {
                let best = p.embeddings.iter().map(|e| cosine(e, query)).fold(f32::NEG_INFINITY, f32::max);
                best.is_finite().then(|| Match { name: n.clone(), similarity: best })
            })
            .max_by(|a, b| a.similarity.total_cmp(&b.similarity))
    }

    /// Reads the gallery at `path`, or an empty one for `model` if the file
    /// does not exist yet. A file written for another model is an error.
    pub fn load_or_new(path: &Path, model: &str, dim: usize) -> Result<Self, GalleryError> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::new(model, dim)),
            Err(source) => return Err(GalleryError::Read { path: path.to_path_buf(), source }),
        };
        let g: Gallery = serde_json::from_slice(&bytes)
            .map_err(|source| GalleryError::Corrupt { path: path.to_path_buf(), source })?;
        if g.model != model || g.dim != dim {
            return Err(GalleryError::WrongModel {
                path: path.to_path_buf(),
                found: format!("{} ({}-d)", g.model, g.dim),
                expected: format!("{model} ({dim}-d)"),
            });
        }
        Ok(g)
    }

    /// Writes the gallery to `path` atomically: readers see the old file or
    /// the new one, never a torn write, even if the process dies midway.
    pub fn save(&self, path: &Path) -> Result<(), GalleryError> {
        let err = |source| GalleryError::Write { path: path.to_path_buf(), source };
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(err)?;
        let tmp = dir.join(format!(
            ".{}.tmp-{}",
            path.file_name().and_then(|n| n.to_str()).unwrap_or("gallery"),
            std::process::id()
        ));
        let json = serde_json::to_vec(self).expect("a gallery always serialises");
        let mut f = std::fs::File::create(&tmp).map_err(err)?;
        f.write_all(&json).map_err(err)?;
        f.sync_all().map_err(err)?;
        drop(f);
        std::fs::rename(&tmp, path).map_err(err)?;
        // Persist the rename itself (the directory entry).
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: &[f32]) -> Vec<f32> {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.iter().map(|x| x / n).collect()
    }

    #[test]
    fn best_match_takes_the_closest_embedding_of_each_person() {
        let mut g = Gallery::new("m", 2);
        g.enroll("ana", 2, vec![unit(&[1.0, 0.0]), unit(&[0.0, 1.0])]);
        g.enroll("bo", 1, vec![unit(&[1.0, 1.0])]);
        let m = g.best_match(&unit(&[0.1, 1.0]), None).unwrap();
        assert_eq!(m.name, "ana");
        assert!((m.similarity - unit(&[0.1, 1.0])[1]).abs() < 1e-6);
        let only_bo = g.best_match(&unit(&[0.1, 1.0]), Some("bo")).unwrap();
        assert_eq!(only_bo.name, "bo");
        assert!(g.best_match(&unit(&[1.0, 0.0]), Some("nobody")).is_none());
    }

    #[test]
    fn enrollment_keeps_the_newest_embeddings() {
        let mut g = Gallery::new("m", 1);
        for i in 0..(MAX_EMBEDDINGS_PER_PERSON + 5) {
            g.enroll("ana", 1, vec![vec![i as f32]]);
        }
        let p = &g.people["ana"];
        assert_eq!(p.embeddings.len(), MAX_EMBEDDINGS_PER_PERSON);
        assert_eq!(p.embeddings[0], vec![5.0]);
        assert_eq!(p.images as usize, MAX_EMBEDDINGS_PER_PERSON + 5);
    }

    #[test]
    fn save_and_load_round_trip_and_reject_another_model() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/gallery.json");
        assert!(Gallery::load_or_new(&path, "m", 2).unwrap().is_empty());
        let mut g = Gallery::new("m", 2);
        g.enroll("ana", 1, vec![unit(&[3.0, 4.0])]);
        g.save(&path).unwrap();
        g.enroll("bo", 1, vec![unit(&[1.0, 0.0])]);
        g.save(&path).unwrap();
        assert_eq!(Gallery::load_or_new(&path, "m", 2).unwrap(), g);
        let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap()).unwrap().collect();
        assert_eq!(leftovers.len(), 1, "temporary files left behind");
        assert!(matches!(Gallery::load_or_new(&path, "other", 2), Err(GalleryError::WrongModel { .. })));
        std::fs::write(&path, b"{not json").unwrap();
        assert!(matches!(Gallery::load_or_new(&path, "m", 2), Err(GalleryError::Corrupt { .. })));
    }
}

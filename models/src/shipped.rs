//! Weight files, on disk or built in: the shipped weights of
//! `models/weights/` are compiled into every binary, so that an installed
//! `flowopt` plans with the learned planner from any directory. A weight
//! file that is named but missing is an error, never a silent fallback.
//!
//! ```
//! use flowopt_models::shipped::Weights;
//! use flowopt_planner::problem::Dim;
//!
//! let flow = Weights::shipped_flow(Dim::Two);
//! assert_eq!(flow.to_string(), "models/weights/flow.safetensors (built in)");
//! assert!(flow.bytes().unwrap().len() > 1000);
//! assert!(Weights::parse("no/such/file.safetensors").bytes().is_err());
//! ```

use std::borrow::Cow;
use std::fmt;
use std::path::{Path, PathBuf};

use flowopt_planner::problem::Dim;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::ModelError;

/// The shipped files: their repository paths and contents.
const FLOW_2D: (&str, &[u8]) = ("models/weights/flow.safetensors", include_bytes!("../weights/flow.safetensors"));
const INIT_2D: (&str, &[u8]) = ("models/weights/init.safetensors", include_bytes!("../weights/init.safetensors"));
const FLOW_3D: (&str, &[u8]) = ("models/weights/flow3d.safetensors", include_bytes!("../weights/flow3d.safetensors"));
const INIT_3D: (&str, &[u8]) = ("models/weights/init3d.safetensors", include_bytes!("../weights/init3d.safetensors"));

/// The word that names the shipped weights in a configuration.
pub const SHIPPED: &str = "shipped";

/// A weight file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Weights {
    /// A file on disk.
    File(PathBuf),
    /// Shipped weights built into the binary.
    Shipped {
        /// Their path in the repository.
        name: &'static str,
        /// Their contents.
        bytes: &'static [u8],
    },
}

impl Weights {
    /// The shipped flow policy for teams of `dim`.
    pub fn shipped_flow(dim: Dim) -> Self {
        let (name, bytes) = match dim {
            Dim::Two => FLOW_2D,
            Dim::Three => FLOW_3D,
        };
        Weights::Shipped { name, bytes }
    }

    /// The shipped SF initialiser for teams of `dim`.
    pub fn shipped_init(dim: Dim) -> Self {
        let (name, bytes) = match dim {
            Dim::Two => INIT_2D,
            Dim::Three => INIT_3D,
        };
        Weights::Shipped { name, bytes }
    }

    /// A file path from a configuration or the command line.
    pub fn parse(text: &str) -> Self {
        Weights::File(PathBuf::from(text))
    }

    /// A file's path relative to `dir` (a configuration file's directory);
    /// built-in weights unchanged.
    pub fn relative_to(&self, dir: &Path) -> Self {
        match self {
            Weights::File(path) => Weights::File(dir.join(path)),
            shipped => shipped.clone(),
        }
    }

    /// The contents.
    pub fn bytes(&self) -> Result<Cow<'static, [u8]>, ModelError> {
        match self {
            Weights::File(path) => std::fs::read(path).map(Cow::Owned).map_err(|e| ModelError::io(path, e)),
            Weights::Shipped { bytes, .. } => Ok(Cow::Borrowed(bytes)),
        }
    }

    /// The file on disk, if it is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            Weights::File(path) => Some(path),
            Weights::Shipped { .. } => None,
        }
    }

    /// The file on disk, or where the built-in weights lie in the
    /// repository (for tools that work from its root).
    pub fn file(&self) -> PathBuf {
        match self {
            Weights::File(path) => path.clone(),
            Weights::Shipped { name, .. } => PathBuf::from(name),
        }
    }
}

impl fmt::Display for Weights {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Weights::File(path) => write!(f, "{}", path.display()),
            Weights::Shipped { name, .. } => write!(f, "{name} (built in)"),
        }
    }
}

/// Which weights a configuration names: a file, or [`SHIPPED`] for the
/// shipped ones of the team's dimension.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum WeightsRef {
    /// The shipped weights for the team's dimension.
    #[default]
    Shipped,
    /// A file (relative paths are resolved against the configuration's
    /// directory by whoever reads it).
    File(PathBuf),
}

impl WeightsRef {
    /// The weights for `dim`: `shipped` picks the shipped file of that kind.
    pub fn resolve(&self, dim: Dim, shipped: fn(Dim) -> Weights) -> Weights {
        match self {
            WeightsRef::Shipped => shipped(dim),
            WeightsRef::File(path) => Weights::File(path.clone()),
        }
    }
}

impl Serialize for WeightsRef {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            WeightsRef::Shipped => serializer.serialize_str(SHIPPED),
            WeightsRef::File(path) => serializer.serialize_str(&path.to_string_lossy()),
        }
    }
}

impl<'de> Deserialize<'de> for WeightsRef {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        Ok(if text == SHIPPED { WeightsRef::Shipped } else { WeightsRef::File(PathBuf::from(text)) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_weights_are_the_repository_files() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        for dim in [Dim::Two, Dim::Three] {
            for w in [Weights::shipped_flow(dim), Weights::shipped_init(dim)] {
                let Weights::Shipped { name, bytes } = &w else { panic!("{w}") };
                assert_eq!(std::fs::read(root.join(name)).unwrap(), *bytes, "{name}");
            }
        }
    }

    #[test]
    fn a_named_file_that_is_missing_is_an_error_naming_it() {
        let err = Weights::parse("/no/such/flow.safetensors").bytes().unwrap_err().to_string();
        assert!(err.contains("/no/such/flow.safetensors"), "{err}");
        let r: WeightsRef = serde_json::from_str("\"shipped\"").unwrap();
        assert_eq!(r.resolve(Dim::Three, Weights::shipped_flow), Weights::shipped_flow(Dim::Three));
        let r: WeightsRef = serde_json::from_str("\"w/f.safetensors\"").unwrap();
        assert_eq!(r.resolve(Dim::Two, Weights::shipped_flow), Weights::File("w/f.safetensors".into()));
    }
}

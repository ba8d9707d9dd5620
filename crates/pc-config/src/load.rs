//! Loading pipeline.toml: `include`s merged, `--set` overrides applied, deserialized, validated;
//! and writing a config (or part of one) back as TOML.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::{validate, ConfigError, LoadedConfig, PipelineConfig};

/// Read `path`, merge its includes, apply `overrides` (`key.path=value`), validate.
pub fn load_config(path: &Path, overrides: &[String]) -> Result<LoadedConfig, ConfigError> {
    let mut stack = Vec::new();
    let mut value = read_tree(path, &mut stack)?;
    for o in overrides {
        apply_override(&mut value, o)
            .map_err(|m| ConfigError::invalid(path, format!("--set {o}: {m}")))?;
        refuse_retired(&value, path, &format!("--set {o}: "))?;
    }
    let text = toml::to_string(&value).map_err(|e| ConfigError::invalid(path, e.to_string()))?;
    let mut config = deserialize(value, path)?;
    config.include.clear();
    validate(&config, path)?;
    let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let cfg = LoadedConfig {
        config,
        path: path.to_path_buf(),
        base_dir,
        text,
    };
    crate::validate::check_paths(&cfg)?;
    Ok(cfg)
}

/// The merged config as [`PipelineConfig`]; a value of the wrong type is named by its key
/// (`raytrace.spp: invalid value: integer \`-1\`, expected u32`), which the merged tree's own
/// errors do not say.
fn deserialize(value: toml::Value, path: &Path) -> Result<PipelineConfig, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let key = e.path().to_string();
        let why = e.inner().message().to_string();
        let msg = match key.as_str() {
            "" | "." => why,
            _ => format!("{key}: {why}"),
        };
        ConfigError::invalid(path, msg)
    })
}

/// Parse a config from text (relative paths resolve against `base_dir`), for tests and tools.
pub fn parse_config(text: &str, base_dir: &Path) -> Result<LoadedConfig, ConfigError> {
    let pseudo = base_dir.join("<inline>");
    let value: toml::Value =
        toml::from_str(text).map_err(|e| ConfigError::invalid(&pseudo, e.to_string()))?;
    refuse_retired(&value, &pseudo, "")?;
    let config = deserialize(value, &pseudo)?;
    validate(&config, &pseudo)?;
    Ok(LoadedConfig {
        config,
        path: pseudo,
        base_dir: base_dir.to_path_buf(),
        text: text.to_string(),
    })
}

/// Keys pcgi once read and reads no longer, with what took their place: a config that sets one
/// is refused with that, where serde's "unknown field" would not say why. (table, key, why)
const RETIRED: &[(&str, &str, &str)] = &[(
    "caustics",
    "self_hit",
    "photons and specular-link paths now pass over the surface they leave within its own zone, \
     as the V-map's rays do (docs/caustics.md, \"Tracing\"); delete the line",
)];

/// A [`RETIRED`] key set in `value` (read from `path`; `what` prefixes the message), refused.
fn refuse_retired(value: &toml::Value, path: &Path, what: &str) -> Result<(), ConfigError> {
    for (table, key, why) in RETIRED {
        if value.get(table).and_then(|t| t.get(key)).is_some() {
            let msg = format!("{what}[{table}] {key} is no longer read: {why}");
            return Err(ConfigError::invalid(path, msg));
        }
    }
    Ok(())
}

fn read_tree(path: &Path, stack: &mut Vec<PathBuf>) -> Result<toml::Value, ConfigError> {
    let canon = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    if stack.contains(&canon) {
        return Err(ConfigError::invalid(path, "include cycle"));
    }
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut value: toml::Value =
        toml::from_str(&text).map_err(|e| ConfigError::invalid(path, e.to_string()))?;
    refuse_retired(&value, path, "")?;
    let dir = path.parent().unwrap_or(Path::new(""));
    // Included files' model paths become absolute (resolved against the included file's
    // folder), so they do not depend on where the top-level file is.
    let abs_dir = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    // Resolve model paths relative to the file that declares them, so an included file keeps
    // pointing at its own PLYs. The top-level file keeps relative paths (resolved at load).
    if !stack.is_empty() {
        if let Some(models) = value.get_mut("models").and_then(|m| m.as_array_mut()) {
            for m in models {
                if let Some(f) = m.get_mut("file") {
                    if let Some(s) = f.as_str() {
                        let p = Path::new(s);
                        if p.is_relative() {
                            *f =
                                toml::Value::String(abs_dir.join(p).to_string_lossy().into_owned());
                        }
                    }
                }
            }
        }
    }
    let includes: Vec<PathBuf> = match value.get("include") {
        None => Vec::new(),
        Some(toml::Value::Array(a)) => a
            .iter()
            .map(|v| {
                v.as_str()
                    .map(|s| dir.join(s))
                    .ok_or_else(|| ConfigError::invalid(path, "`include` must be a list of paths"))
            })
            .collect::<Result<_, _>>()?,
        Some(_) => {
            return Err(ConfigError::invalid(
                path,
                "`include` must be a list of paths",
            ))
        }
    };
    if let Some(t) = value.as_table_mut() {
        t.remove("include");
    }
    stack.push(canon);
    let mut merged = toml::Value::Table(Default::default());
    for inc in &includes {
        let sub = read_tree(inc, stack)?;
        merge(&mut merged, sub);
    }
    stack.pop();
    merge(&mut merged, value);
    Ok(merged)
}

/// Deep-merge `top` over `base`: tables merge key by key, arrays of tables (models, lights)
/// concatenate, everything else is replaced.
fn merge(base: &mut toml::Value, top: toml::Value) {
    match (base, top) {
        (toml::Value::Table(b), toml::Value::Table(t)) => {
            for (k, v) in t {
                match b.get_mut(&k) {
                    Some(existing) => merge(existing, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (toml::Value::Array(b), toml::Value::Array(t))
            if t.iter().all(|v| v.is_table()) && !t.is_empty() =>
        {
            b.extend(t);
        }
        (b, t) => *b = t,
    }
}

/// Why a `--set KEY=VALUE` could not be applied.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum OverrideError {
    #[error("expected key=value")]
    NoEquals,
    #[error("empty key")]
    EmptyKey,
    #[error("`{0}` is not an index into an array")]
    NotAnIndex(String),
    #[error("index {index} is out of range (array has {len})")]
    OutOfRange { index: usize, len: usize },
    #[error("`{0}`: the key above it is not a table")]
    NotATable(String),
}

/// Apply one `a.b.c=value` override. The value is parsed as TOML (`0.5`, `[1, 2, 3]`, `"x"`,
/// `true`); anything that does not parse is taken as a string. Array elements are addressed by
/// index (`models.0.material=glass`).
pub fn apply_override(root: &mut toml::Value, spec: &str) -> Result<(), OverrideError> {
    let (key, raw) = spec.split_once('=').ok_or(OverrideError::NoEquals)?;
    let key = key.trim();
    if key.is_empty() {
        return Err(OverrideError::EmptyKey);
    }
    let raw = raw.trim();
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = root;
    for (i, part) in parts.iter().enumerate() {
        let last = i + 1 == parts.len();
        cur = match cur {
            toml::Value::Table(t) => {
                if last {
                    t.insert(part.to_string(), value);
                    return Ok(());
                }
                t.entry(part.to_string())
                    .or_insert_with(|| toml::Value::Table(Default::default()))
            }
            toml::Value::Array(a) => {
                let idx: usize = part
                    .parse()
                    .map_err(|_| OverrideError::NotAnIndex(part.to_string()))?;
                let len = a.len();
                let slot = a
                    .get_mut(idx)
                    .ok_or(OverrideError::OutOfRange { index: idx, len })?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
            _ => return Err(OverrideError::NotATable(part.to_string())),
        };
    }
    Ok(())
}

/// `value` as TOML text, with every float written as the shortest text of the `f32` it holds
/// (the config's numbers are `f32`: 0.9 stays `0.9`, not `0.8999999761581421`).
pub fn to_toml<T: Serialize + ?Sized>(value: &T) -> Result<String, toml::ser::Error> {
    let mut v = toml::Value::try_from(value)?;
    shorten_floats(&mut v);
    toml::to_string(&v)
}

fn shorten_floats(v: &mut toml::Value) {
    match v {
        toml::Value::Float(x) if x.is_finite() => {
            *x = (*x as f32).to_string().parse().unwrap_or(*x);
        }
        toml::Value::Array(a) => a.iter_mut().for_each(shorten_floats),
        toml::Value::Table(t) => t.iter_mut().for_each(|(_, v)| shorten_floats(v)),
        _ => {}
    }
}

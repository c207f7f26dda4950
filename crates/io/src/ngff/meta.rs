//! The OME-Zarr metadata of one image: its axes and the scale and translation of its first (full-resolution)
//! dataset, from the `multiscales` attribute of versions 0.4 (Zarr v2's `.zattrs`), 0.5 and 0.6 (Zarr v3's
//! `zarr.json`, under `ome`), and what its level-0 array says of itself (`.zarray` or `zarr.json`).

use std::path::Path;

use serde_json::{Map, Value};

use crate::error::{Error, Result};
use crate::sample::StoredType;

/// The OME-Zarr versions read.
pub(super) const VERSIONS: [&str; 3] = ["0.4", "0.5", "0.6"];

/// What an axis is, from its `type` (or, where a 0.4 file leaves the type out, its name).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum AxisKind {
    Space,
    Time,
    Channel,
    /// Any other type: allowed with one sample.
    Other(String),
}

impl AxisKind {
    /// What samples along such an axis are, in a message about too many of them.
    pub(super) fn samples(&self) -> String {
        match self {
            Self::Space => "samples on a fourth space axis".to_owned(),
            Self::Time => "samples on a second time axis".to_owned(),
            Self::Channel => "channels".to_owned(),
            Self::Other(t) => format!("samples on an axis of type {t:?}"),
        }
    }
}

/// One axis of the image, in the array's order (slowest first).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Axis {
    pub name: String,
    pub kind: AxisKind,
    /// The `unit`, as written.
    pub unit: Option<String>,
    /// RFC-4's anatomical `orientation` value, as written.
    pub orientation: Option<String>,
}

/// The image's metadata: the axes and, per axis, the combined scale and translation from array index to the
/// axis's coordinate (in its own unit): coordinate = scale · index + translation.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Image {
    pub version: String,
    /// The path of the full-resolution array inside the store, from the root.
    pub array_path: String,
    pub axes: Vec<Axis>,
    pub scale: Vec<f64>,
    pub translation: Vec<f64>,
    /// How many resolution levels the multiscale has (only the first is read).
    pub levels: usize,
}

/// What the level-0 array's own metadata says.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct ArrayMeta {
    pub shape: Vec<u64>,
    pub stored: StoredType,
    /// The shape of the chunks read one at a time (a sharded array's inner chunks, and its shards).
    pub chunk_shapes: Vec<Vec<u64>>,
}

/// Whether the folder `dir` is a Zarr store (a v2 group's `.zattrs` or `.zgroup`, or a v3 `zarr.json`), which
/// [`super::read()`] tells an OME-Zarr image from any other.
#[must_use]
pub fn looks_like_zarr(dir: &Path) -> bool {
    ["zarr.json", ".zattrs", ".zgroup"].iter().any(|f| dir.join(f).is_file())
}

/// Where the image's metadata is: a Zarr v2 group's `.zattrs` or a v3 group's `zarr.json`, read from `root`;
/// `group` is the group's path inside the store ("" for the root).
pub(super) fn read_image(root: &Path, group: &str) -> Result<Image> {
    let (attrs, v3) = group_attributes(root, group)?;
    let ome = if v3 {
        match attrs.get("ome") {
            Some(Value::Object(o)) => o.clone(),
            _ => {
                return Err(Error::invalid(root, "the Zarr v3 group has no \"ome\" attributes: not an OME-Zarr image"));
            }
        }
    } else {
        attrs
    };
    if ome.contains_key("bioformats2raw.layout") && !ome.contains_key("multiscales") && group.is_empty() {
        // bioformats2raw's layout: the images are the groups 0, 1, ...; the first is read.
        return read_image(root, "0");
    }
    let Some(Value::Array(multiscales)) = ome.get("multiscales") else {
        let what = if ome.contains_key("plate") || ome.contains_key("well") {
            "an OME-Zarr plate or well (a screen of many images); open one image's folder instead"
        } else {
            "no \"multiscales\": not an OME-Zarr image"
        };
        return Err(Error::unsupported(root, what));
    };
    let Some(Value::Object(ms)) = multiscales.first() else {
        return Err(Error::invalid(root, "\"multiscales\" is empty"));
    };
    let version = match (v3, ome.get("version"), ms.get("version")) {
        (true, Some(Value::String(v)), _) | (false, _, Some(Value::String(v))) => v.clone(),
        _ => return Err(Error::invalid(root, "the multiscale does not give its OME-Zarr version")),
    };
    if !VERSIONS.contains(&version.as_str()) {
        return Err(Error::unsupported(
            root,
            format!("OME-Zarr version {version}; warpbench reads versions {}", VERSIONS.join(", ")),
        ));
    }
    let datasets = match ms.get("datasets") {
        Some(Value::Array(d)) if !d.is_empty() => d,
        _ => return Err(Error::invalid(root, "the multiscale has no datasets")),
    };
    let Some(Value::Object(dataset)) = datasets.first() else {
        return Err(Error::invalid(root, "the multiscale's first dataset is not an object"));
    };
    let Some(Value::String(path)) = dataset.get("path") else {
        return Err(Error::invalid(root, "the multiscale's first dataset has no \"path\""));
    };
    let array_path = if group.is_empty() { path.clone() } else { format!("{group}/{path}") };
    let (axes, map) =
        if version == "0.6" { transforms_06(root, ms, dataset)? } else { transforms_04(root, ms, dataset)? };
    Ok(Image { version, array_path, axes, scale: map.scale, translation: map.translation, levels: datasets.len() })
}

/// A 0.6 multiscale's field transformation (RFC-5's `displacements` or `coordinates`): where its field is, and the
/// axes its components follow.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct FieldEntry {
    /// `displacements` or `coordinates`.
    pub kind: String,
    /// Where the field is in the store: the multiscale's first dataset (a standalone field), or a group that is a
    /// multiscale of its own.
    pub group: String,
    /// The names of the output coordinate system's space axes, in order (the i-th component is along the i-th
    /// axis); empty where the system is not declared.
    pub component_axes: Vec<String>,
}

/// The field transformation of the root group's first multiscale, if it is a 0.6 one and has one.
pub(super) fn field_entry(root: &Path) -> Result<Option<FieldEntry>> {
    let (attrs, v3) = group_attributes(root, "")?;
    let Some(Value::Object(ome)) = attrs.get("ome").filter(|_| v3) else { return Ok(None) };
    let Some(ms) = ome.get("multiscales").and_then(Value::as_array).and_then(|m| m.first()) else { return Ok(None) };
    let Some(list) = ms.get("coordinateTransformations").and_then(Value::as_array) else { return Ok(None) };
    let Some(t) =
        list.iter().find(|t| matches!(t.get("type").and_then(Value::as_str), Some("displacements" | "coordinates")))
    else {
        return Ok(None);
    };
    let kind = t.get("type").and_then(Value::as_str).unwrap_or_default().to_owned();
    let Some(path) = t.get("path").and_then(Value::as_str) else {
        return Err(Error::invalid(root, format!("the {kind} transformation has no \"path\" to its field")));
    };
    let datasets: Vec<&str> = ms
        .get("datasets")
        .and_then(Value::as_array)
        .map(|d| d.iter().filter_map(|d| d.get("path").and_then(Value::as_str)).collect())
        .unwrap_or_default();
    let group = match datasets.iter().position(|&d| d == path) {
        Some(0) => String::new(),
        Some(level) => {
            return Err(Error::unsupported(
                root,
                format!("the {kind} transformation's field is resolution level {level}, not the full one"),
            ));
        }
        None => path.trim_matches('/').to_owned(),
    };
    let output = t.get("output").and_then(|o| o.get("name")).and_then(Value::as_str);
    let component_axes = ms
        .get("coordinateSystems")
        .and_then(Value::as_array)
        .and_then(|systems| systems.iter().find(|s| s.get("name").and_then(Value::as_str) == output))
        .and_then(|s| parse_axes(root, s.get("axes")).ok())
        .map(|axes| axes.into_iter().filter(|a| a.kind == AxisKind::Space).map(|a| a.name).collect())
        .unwrap_or_default();
    Ok(Some(FieldEntry { kind, group, component_axes }))
}

/// The attributes of the group at `group`, and whether it is a Zarr v3 group.
fn group_attributes(root: &Path, group: &str) -> Result<(Map<String, Value>, bool)> {
    let dir = root.join(group);
    let v3 = dir.join("zarr.json");
    if v3.is_file() {
        let json = read_json(&v3)?;
        if json.get("node_type").and_then(Value::as_str) != Some("group") {
            return Err(Error::invalid(&v3, "not a Zarr group (node_type is not \"group\")"));
        }
        return match json.get("attributes") {
            Some(Value::Object(a)) => Ok((a.clone(), true)),
            _ => Err(Error::invalid(&v3, "the group has no attributes: not an OME-Zarr image")),
        };
    }
    let v2 = dir.join(".zattrs");
    if v2.is_file() {
        return match read_json(&v2)? {
            Value::Object(a) => Ok((a, false)),
            _ => Err(Error::invalid(&v2, "not a JSON object")),
        };
    }
    Err(Error::unsupported(root, format!("no zarr.json or .zattrs in {}: not an OME-Zarr image", dir.display())))
}

/// The largest metadata file read.
const MAX_JSON_BYTES: u64 = 16 << 20;

fn read_json(path: &Path) -> Result<Value> {
    let text = crate::files::read_small_text(path, MAX_JSON_BYTES, "Zarr metadata")?;
    serde_json::from_str(&text).map_err(|e| Error::invalid(path, format!("not valid JSON: {e}")))
}

/// Per-axis scale and translation: coordinate = scale · index + translation.
#[derive(Clone, Debug, PartialEq)]
struct AxisMap {
    scale: Vec<f64>,
    translation: Vec<f64>,
}

impl AxisMap {
    fn identity(n: usize) -> Self {
        Self { scale: vec![1.0; n], translation: vec![0.0; n] }
    }

    /// Applies one transform after the map (`kind` is its `type`).
    fn then(&mut self, root: &Path, t: &Map<String, Value>) -> Result<()> {
        let n = self.scale.len();
        let kind = t.get("type").and_then(Value::as_str).unwrap_or("");
        match kind {
            "identity" => {}
            "scale" => {
                let s = numbers(root, t, "scale", n)?;
                for ((scale, translation), s) in self.scale.iter_mut().zip(&mut self.translation).zip(s) {
                    *scale *= s;
                    *translation *= s;
                }
            }
            "translation" => {
                let d = numbers(root, t, "translation", n)?;
                for (translation, d) in self.translation.iter_mut().zip(d) {
                    *translation += d;
                }
            }
            "sequence" => {
                let Some(Value::Array(steps)) = t.get("transformations") else {
                    return Err(Error::invalid(root, "a \"sequence\" transformation without \"transformations\""));
                };
                for step in steps {
                    self.then(root, object(root, step, "a transformation")?)?;
                }
            }
            other => {
                return Err(Error::unsupported(
                    root,
                    format!(
                        "the image's coordinate transformation is {other:?}; warpbench reads identity, scale, \
                         translation and sequences of them (a rotation or affine has no place in these versions' \
                         image grid yet)"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// `t[key]`: `n` finite numbers, each non-zero for a scale (a transformation stored in a binary `path` is refused).
fn numbers(root: &Path, t: &Map<String, Value>, key: &str, n: usize) -> Result<Vec<f64>> {
    let Some(Value::Array(v)) = t.get(key) else {
        let why = if t.contains_key("path") { " (stored in an array by \"path\", which is not read)" } else { "" };
        return Err(Error::unsupported(root, format!("a {key} transformation without its numbers{why}")));
    };
    let v: Vec<f64> = v.iter().map(Value::as_f64).collect::<Option<_>>().unwrap_or_default();
    if v.len() != n || v.iter().any(|x| !x.is_finite()) || (key == "scale" && v.contains(&0.0)) {
        return Err(Error::invalid(root, format!("the {key} {:?} does not give {n} finite numbers", t.get(key))));
    }
    Ok(v)
}

fn object<'a>(root: &Path, v: &'a Value, what: &str) -> Result<&'a Map<String, Value>> {
    v.as_object().ok_or_else(|| Error::invalid(root, format!("{what} is not a JSON object")))
}

/// The name of the coordinate system a 0.6 transformation maps to.
fn output(t: &Map<String, Value>) -> Option<&str> {
    t.get("output").and_then(|o| o.get("name")).and_then(Value::as_str)
}

/// A list of transformations applied in order.
fn apply_all(root: &Path, map: &mut AxisMap, list: Option<&Value>) -> Result<()> {
    match list {
        None => Ok(()),
        Some(Value::Array(ts)) => ts.iter().try_for_each(|t| map.then(root, object(root, t, "a transformation")?)),
        Some(_) => Err(Error::invalid(root, "\"coordinateTransformations\" is not a list")),
    }
}

/// 0.4 and 0.5: the multiscale's `axes`; the dataset's transformations, then the multiscale's.
fn transforms_04(root: &Path, ms: &Map<String, Value>, dataset: &Map<String, Value>) -> Result<(Vec<Axis>, AxisMap)> {
    let axes = parse_axes(root, ms.get("axes"))?;
    let mut map = AxisMap::identity(axes.len());
    if dataset.get("coordinateTransformations").is_none() {
        return Err(Error::invalid(root, "the first dataset has no \"coordinateTransformations\" (its scale)"));
    }
    apply_all(root, &mut map, dataset.get("coordinateTransformations"))?;
    apply_all(root, &mut map, ms.get("coordinateTransformations"))?;
    Ok((axes, map))
}

/// 0.6: the dataset's transformation (input the array, output a coordinate system of the multiscale), then any of
/// the multiscale's whose input is that system; the axes are those of the system reached.
fn transforms_06(root: &Path, ms: &Map<String, Value>, dataset: &Map<String, Value>) -> Result<(Vec<Axis>, AxisMap)> {
    let Some(Value::Array(systems)) = ms.get("coordinateSystems") else {
        return Err(Error::invalid(root, "the 0.6 multiscale has no \"coordinateSystems\""));
    };
    let system = |name: Option<&str>| -> Result<Vec<Axis>> {
        let found = systems.iter().filter_map(Value::as_object).find(|s| match name {
            Some(n) => s.get("name").and_then(Value::as_str) == Some(n),
            None => true,
        });
        match found {
            Some(s) => parse_axes(root, s.get("axes")),
            None => Err(Error::invalid(root, format!("no coordinate system named {name:?}"))),
        }
    };
    let Some(Value::Array(list)) = dataset.get("coordinateTransformations") else {
        return Err(Error::invalid(root, "the first dataset has no \"coordinateTransformations\" (its scale)"));
    };
    let [t] = list.as_slice() else {
        return Err(Error::invalid(root, "the first dataset must have one coordinate transformation"));
    };
    let t = object(root, t, "a transformation")?;
    let mut reached = output(t).map(str::to_owned);
    let mut axes = system(reached.as_deref())?;
    let mut map = AxisMap::identity(axes.len());
    map.then(root, t)?;
    if let Some(Value::Array(more)) = ms.get("coordinateTransformations") {
        for t in more {
            let t = object(root, t, "a transformation")?;
            let input = t.get("input").and_then(|i| i.get("name")).and_then(Value::as_str);
            if input.is_some() && input == reached.as_deref() {
                map.then(root, t)?;
                reached = output(t).map(str::to_owned);
                let next = system(reached.as_deref())?;
                if next.len() != axes.len() {
                    return Err(Error::unsupported(root, "a coordinate transformation changes the number of axes"));
                }
                axes = next;
            }
        }
    }
    Ok((axes, map))
}

fn parse_axes(root: &Path, axes: Option<&Value>) -> Result<Vec<Axis>> {
    let Some(Value::Array(list)) = axes else {
        return Err(Error::invalid(root, "the multiscale has no \"axes\""));
    };
    list.iter()
        .map(|a| {
            let a = object(root, a, "an axis")?;
            let text = |k: &str| a.get(k).and_then(Value::as_str).map(str::to_owned);
            let Some(name) = text("name") else {
                return Err(Error::invalid(root, "an axis has no name"));
            };
            let kind = match (text("type").as_deref(), name.as_str()) {
                (Some("space"), _) | (None, "x" | "y" | "z") => AxisKind::Space,
                (Some("time"), _) | (None, "t") => AxisKind::Time,
                (Some("channel"), _) | (None, "c") => AxisKind::Channel,
                (Some(other), _) => AxisKind::Other(other.to_owned()),
                (None, _) => AxisKind::Other(String::new()),
            };
            let orientation = a.get("orientation").and_then(|o| o.get("value")).and_then(Value::as_str);
            Ok(Axis { name, kind, unit: text("unit"), orientation: orientation.map(str::to_owned) })
        })
        .collect()
}

/// The level-0 array's shape, sample type and chunk shapes, from its `.zarray` (v2) or `zarr.json` (v3).
pub(super) fn read_array_meta(root: &Path, array_path: &str) -> Result<ArrayMeta> {
    let dir = root.join(array_path);
    let v3 = dir.join("zarr.json");
    let (json, file, v3) = if v3.is_file() {
        (read_json(&v3)?, v3, true)
    } else {
        let v2 = dir.join(".zarray");
        if !v2.is_file() {
            return Err(Error::invalid(
                root,
                format!("the image's array {array_path:?} is missing (no zarr.json or .zarray)"),
            ));
        }
        (read_json(&v2)?, v2, false)
    };
    let ints = |v: Option<&Value>| -> Option<Vec<u64>> { v?.as_array()?.iter().map(Value::as_u64).collect() };
    let Some(shape) = ints(json.get("shape")) else {
        return Err(Error::invalid(&file, "no \"shape\" of whole numbers"));
    };
    let (type_name, mut chunk_shapes) = if v3 {
        let chunk = ints(json.pointer("/chunk_grid/configuration/chunk_shape"));
        let mut shapes: Vec<Vec<u64>> = chunk.into_iter().collect();
        if let Some(Value::Array(codecs)) = json.get("codecs") {
            for c in codecs {
                if c.get("name").and_then(Value::as_str) == Some("sharding_indexed") {
                    shapes.extend(ints(c.pointer("/configuration/chunk_shape")));
                }
            }
        }
        (json.get("data_type").and_then(Value::as_str).unwrap_or("").to_owned(), shapes)
    } else {
        let dtype = json.get("dtype").and_then(Value::as_str).unwrap_or("");
        (dtype.to_owned(), ints(json.get("chunks")).into_iter().collect())
    };
    if chunk_shapes.is_empty() {
        return Err(Error::invalid(&file, "no regular chunk shape"));
    }
    chunk_shapes.dedup();
    let stored = stored_type(&type_name, v3).ok_or_else(|| {
        Error::unsupported(&file, format!("samples of type {type_name:?}; warpbench reads integers and floats"))
    })?;
    Ok(ArrayMeta { shape, stored, chunk_shapes })
}

/// The sample type of a v3 `data_type` or a v2 NumPy `dtype` (`<i2`, `>f4`, `|u1`, ...).
fn stored_type(name: &str, v3: bool) -> Option<StoredType> {
    let base = if v3 {
        name
    } else {
        match name.as_bytes().first() {
            Some(b'<' | b'>' | b'|' | b'=') => &name[1..],
            _ => name,
        }
    };
    Some(match base {
        "uint8" | "u1" => StoredType::U8,
        "int8" | "i1" => StoredType::I8,
        "uint16" | "u2" => StoredType::U16,
        "int16" | "i2" => StoredType::I16,
        "uint32" | "u4" => StoredType::U32,
        "int32" | "i4" => StoredType::I32,
        "uint64" | "u8" => StoredType::U64,
        "int64" | "i8" => StoredType::I64,
        "float32" | "f4" => StoredType::F32,
        "float64" | "f8" => StoredType::F64,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn v2_and_v3_type_names_are_the_same_types() {
        assert_eq!(stored_type("<i2", false), Some(StoredType::I16));
        assert_eq!(stored_type(">i4", false), Some(StoredType::I32));
        assert_eq!(stored_type("|u1", false), Some(StoredType::U8));
        assert_eq!(stored_type("<f8", false), Some(StoredType::F64));
        assert_eq!(stored_type("uint16", true), Some(StoredType::U16));
        assert_eq!(stored_type("float32", true), Some(StoredType::F32));
        assert_eq!(stored_type("<c8", false), None);
        assert_eq!(stored_type("bool", true), None);
        // NumPy's u8 and i8 are 8 bytes; Zarr v3's uint8 and int8 are 1.
        assert_eq!(stored_type("<u8", false), Some(StoredType::U64));
        assert_eq!(stored_type("uint8", true), Some(StoredType::U8));
    }

    #[test]
    fn transformations_compose_in_order() {
        let root = Path::new("x.ome.zarr");
        let mut m = AxisMap::identity(2);
        let t = |v: Value| v.as_object().cloned().expect("object");
        m.then(root, &t(serde_json::json!({"type": "scale", "scale": [2.0, 3.0]}))).expect("scale");
        m.then(root, &t(serde_json::json!({"type": "translation", "translation": [1.0, -1.0]}))).expect("shift");
        m.then(root, &t(serde_json::json!({"type": "scale", "scale": [10.0, 0.5]}))).expect("scale");
        // index → 10·(2i + 1) and 0.5·(3j − 1).
        assert_eq!(m, AxisMap { scale: vec![20.0, 1.5], translation: vec![10.0, -0.5] });
        let e = m.then(root, &t(serde_json::json!({"type": "affine", "affine": [[1.0]]}))).expect_err("affine");
        assert!(e.to_string().contains("\"affine\""), "{e}");
        let e = m.then(root, &t(serde_json::json!({"type": "scale", "scale": [0.0, 1.0]}))).expect_err("zero");
        assert!(e.to_string().contains("finite"), "{e}");
    }
}

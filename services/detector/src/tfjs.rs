//! Converter from a TensorFlow.js graph model (`model.json` + weight shards)
//! to vlnav's graph format: the topology as [`GraphDef`] JSON with integer
//! constants inline, float constants as safetensors (float16 weights stay
//! float16, bit for bit).

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::Value as Json;

use crate::graph::{Attr, GRAPH_FORMAT, GraphDef, GraphInput, IntConst, NodeDef};

#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("model.json: {0}")]
    Json(#[from] serde_json::Error),
    #[error("model.json: {0}")]
    Format(String),
    #[error("writing safetensors: {0}")]
    Safetensors(#[from] safetensors::SafeTensorError),
}

fn format_err(msg: impl Into<String>) -> ConvertError {
    ConvertError::Format(msg.into())
}

/// A float constant: safetensors dtype, shape and little-endian bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatConst {
    pub name: String,
    pub dtype: safetensors::Dtype,
    pub shape: Vec<usize>,
    pub bytes: Vec<u8>,
}

/// The converted model.
#[derive(Clone, Debug)]
pub struct Converted {
    pub graph: GraphDef,
    pub floats: Vec<FloatConst>,
}

fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a' + 26) as u32,
            b'0'..=b'9' => (c - b'0' + 52) as u32,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => return None,
        })
    };
    let clean: Vec<u8> = s.bytes().filter(|&c| c != b'=' && !c.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(clean.len() * 3 / 4);
    for chunk in clean.chunks(4) {
        let mut acc = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            acc |= val(c)? << (18 - 6 * i);
        }
        let bytes = [(acc >> 16) as u8, (acc >> 8) as u8, acc as u8];
        out.extend_from_slice(&bytes[..chunk.len().saturating_sub(1)]);
    }
    Some(out)
}

fn as_i64(v: &Json) -> Option<i64> {
    match v {
        Json::String(s) => s.parse().ok(),
        Json::Number(n) => n.as_i64(),
        _ => None,
    }
}

/// TF AttrValue JSON → [`Attr`]; kinds the interpreter never reads (types, shapes) are dropped.
fn convert_attr(v: &Json) -> Option<Attr> {
    let obj = v.as_object()?;
    if let Some(i) = obj.get("i") {
        return as_i64(i).map(Attr::Int);
    }
    if let Some(f) = obj.get("f") {
        return f.as_f64().map(Attr::Float);
    }
    if let Some(b) = obj.get("b") {
        return b.as_bool().map(Attr::Bool);
    }
    if let Some(s) = obj.get("s").and_then(|s| s.as_str()) {
        return base64_decode(s).and_then(|b| String::from_utf8(b).ok()).map(Attr::Str);
    }
    if let Some(list) = obj.get("list").and_then(|l| l.as_object()) {
        if let Some(is) = list.get("i").and_then(|i| i.as_array()) {
            return is.iter().map(as_i64).collect::<Option<Vec<_>>>().map(Attr::Ints);
        }
        if list.is_empty() {
            return Some(Attr::Ints(vec![]));
        }
    }
    None
}

/// Converts a TFJS graph model: `model_json` is the parsed `model.json`,
/// `weights` the concatenated weight shards in manifest order.
pub fn convert(model_json: &Json, weights: &[u8], source: &str) -> Result<Converted, ConvertError> {
    if model_json.get("format").and_then(|f| f.as_str()) != Some("graph-model") {
        return Err(format_err("not a TFJS graph model (format != \"graph-model\")"));
    }
    let topology = model_json.get("modelTopology").ok_or_else(|| format_err("no modelTopology"))?;
    let nodes_json = topology.get("node").and_then(|n| n.as_array()).ok_or_else(|| format_err("no nodes"))?;
    if topology.get("library").and_then(|l| l.get("function")).and_then(|f| f.as_array()).is_some_and(|f| !f.is_empty())
    {
        return Err(format_err("graphs with functions (control flow) are not supported"));
    }

    // Weights, in manifest order.
    let mut floats = Vec::new();
    let mut ints: BTreeMap<String, IntConst> = BTreeMap::new();
    let mut offset = 0usize;
    let groups =
        model_json.get("weightsManifest").and_then(|m| m.as_array()).ok_or_else(|| format_err("no weightsManifest"))?;
    for group in groups {
        for w in group.get("weights").and_then(|w| w.as_array()).into_iter().flatten() {
            let name = w.get("name").and_then(|n| n.as_str()).ok_or_else(|| format_err("weight without a name"))?;
            let shape: Vec<usize> = w
                .get("shape")
                .and_then(|s| s.as_array())
                .ok_or_else(|| format_err(format!("{name}: no shape")))?
                .iter()
                .map(|d| d.as_u64().map(|d| d as usize))
                .collect::<Option<_>>()
                .ok_or_else(|| format_err(format!("{name}: bad shape")))?;
            let numel: usize = shape.iter().product();
            let dtype = w.get("dtype").and_then(|d| d.as_str()).unwrap_or("");
            let quant = w.get("quantization").and_then(|q| q.get("dtype")).and_then(|d| d.as_str());
            let (st_dtype, width) = match (dtype, quant) {
                ("float32", None) => (Some(safetensors::Dtype::F32), 4),
                ("float32", Some("float16")) => (Some(safetensors::Dtype::F16), 2),
                ("int32", None) => (None, 4),
                (d, q) => {
                    return Err(format_err(format!("{name}: dtype {d} with quantization {q:?} is not supported")));
                }
            };
            let len = numel * width;
            let bytes = weights
                .get(offset..offset + len)
                .ok_or_else(|| format_err(format!("weights end inside {name} (offset {offset}, {len} bytes)")))?;
            offset += len;
            match st_dtype {
                Some(dtype) => floats.push(FloatConst { name: name.to_string(), dtype, shape, bytes: bytes.to_vec() }),
                None => {
                    let values =
                        bytes.chunks_exact(4).map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as i64).collect();
                    ints.insert(name.to_string(), IntConst { shape, values });
                }
            }
        }
    }
    if offset != weights.len() {
        return Err(format_err(format!(
            "the manifest describes {offset} bytes of weights, the shards hold {}",
            weights.len()
        )));
    }
    let float_names: std::collections::HashSet<&str> = floats.iter().map(|f| f.name.as_str()).collect();

    let mut nodes = Vec::with_capacity(nodes_json.len());
    let mut inputs = Vec::new();
    for n in nodes_json {
        let name = n.get("name").and_then(|s| s.as_str()).ok_or_else(|| format_err("node without a name"))?.to_string();
        let op = n.get("op").and_then(|s| s.as_str()).ok_or_else(|| format_err(format!("{name}: no op")))?.to_string();
        let node_inputs: Vec<String> = n
            .get("input")
            .and_then(|i| i.as_array())
            .map(|a| a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect())
            .unwrap_or_default();
        let mut attrs = BTreeMap::new();
        if let Some(obj) = n.get("attr").and_then(|a| a.as_object()) {
            for (k, v) in obj {
                if let Some(a) = convert_attr(v) {
                    attrs.insert(k.clone(), a);
                }
            }
        }
        let mut int_value = None;
        if op == "Const" {
            int_value = ints.remove(&name);
            if int_value.is_none() && !float_names.contains(name.as_str()) {
                return Err(format_err(format!("constant {name} has no weights")));
            }
        }
        if op == "Placeholder" {
            let shape: Vec<usize> = n
                .pointer("/attr/shape/shape/dim")
                .and_then(|d| d.as_array())
                .ok_or_else(|| format_err(format!("placeholder {name} has no static shape")))?
                .iter()
                .map(|d| d.get("size").and_then(as_i64).filter(|&s| s > 0).map(|s| s as usize))
                .collect::<Option<_>>()
                .ok_or_else(|| format_err(format!("placeholder {name} has a dynamic shape")))?;
            inputs.push(GraphInput { name: name.clone(), shape });
        }
        nodes.push(NodeDef { name, op, inputs: node_inputs, attrs, int_value });
    }

    // Outputs: the signature's, sorted by name (Identity, Identity_1, …), else every Identity sink.
    let mut outputs: Vec<String> = model_json
        .pointer("/signature/outputs")
        .and_then(|o| o.as_object())
        .map(|o| {
            o.values()
                .filter_map(|v| v.get("name").and_then(|n| n.as_str()))
                .map(|n| n.trim_end_matches(":0").to_string())
                .collect()
        })
        .unwrap_or_default();
    if outputs.is_empty() {
        outputs = nodes.iter().filter(|n| n.op == "Identity").map(|n| n.name.clone()).collect();
    }
    outputs.sort_by_key(|n| {
        let suffix = n.rsplit_once('_').and_then(|(_, s)| s.parse::<u32>().ok());
        (n.split('_').next().unwrap_or("").to_string(), suffix.map(|s| s + 1).unwrap_or(0))
    });
    Ok(Converted {
        graph: GraphDef { format: GRAPH_FORMAT.into(), source: source.into(), inputs, outputs, nodes },
        floats,
    })
}

fn io_err(path: &Path, source: std::io::Error) -> ConvertError {
    ConvertError::Io { path: path.display().to_string(), source }
}

/// Reads `model.json` and its shards from disk and converts them.
pub fn convert_files(model_json: &Path) -> Result<Converted, ConvertError> {
    let text = std::fs::read_to_string(model_json).map_err(|e| io_err(model_json, e))?;
    let json: Json = serde_json::from_str(&text)?;
    let dir = model_json.parent().unwrap_or(Path::new("."));
    let mut weights = Vec::new();
    for group in json.get("weightsManifest").and_then(|m| m.as_array()).into_iter().flatten() {
        for p in group.get("paths").and_then(|p| p.as_array()).into_iter().flatten() {
            let shard = dir.join(p.as_str().ok_or_else(|| format_err("bad shard path"))?);
            weights.extend(std::fs::read(&shard).map_err(|e| io_err(&shard, e))?);
        }
    }
    convert(&json, &weights, &model_json.display().to_string())
}

/// Writes the graph JSON and the float constants.
pub fn write(converted: &Converted, graph_path: &Path, weights_path: &Path) -> Result<(), ConvertError> {
    let views: Vec<(String, safetensors::tensor::TensorView<'_>)> = converted
        .floats
        .iter()
        .map(|f| Ok((f.name.clone(), safetensors::tensor::TensorView::new(f.dtype, f.shape.clone(), &f.bytes)?)))
        .collect::<Result<_, safetensors::SafeTensorError>>()?;
    let mut meta = std::collections::HashMap::new();
    meta.insert("source".to_string(), converted.graph.source.clone());
    safetensors::tensor::serialize_to_file(views, &Some(meta), weights_path)?;
    let json = serde_json::to_string_pretty(&converted.graph)?;
    std::fs::write(graph_path, json).map_err(|e| io_err(graph_path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_decodes_attribute_strings() {
        assert_eq!(base64_decode("VkFMSUQ=").unwrap(), b"VALID");
        assert_eq!(base64_decode("TkhXQw==").unwrap(), b"NHWC");
        assert!(base64_decode("V!").is_none());
    }

    #[test]
    fn converts_a_small_graph_model() {
        let model = serde_json::json!({
            "format": "graph-model",
            "modelTopology": {"node": [
                {"name": "x", "op": "Placeholder", "attr": {"shape": {"shape": {"dim": [{"size": "1"}, {"size": "2"}]}}, "dtype": {"type": "DT_FLOAT"}}},
                {"name": "w", "op": "Const"},
                {"name": "axis", "op": "Const"},
                {"name": "y", "op": "Add", "input": ["x", "w"]},
                {"name": "act", "op": "LeakyRelu", "input": ["y"], "attr": {"alpha": {"f": 0.1}, "padding": {"s": "VkFMSUQ="}, "strides": {"list": {"i": ["1", "2"]}}}},
                {"name": "Identity", "op": "Identity", "input": ["act"]}
            ]},
            "weightsManifest": [{"paths": ["m.bin"], "weights": [
                {"name": "w", "shape": [2], "dtype": "float32", "quantization": {"dtype": "float16", "original_dtype": "float32"}},
                {"name": "axis", "shape": [], "dtype": "int32"}
            ]}]
        });
        // w = [1.0, -2.0] as f16, axis = -1 as i32.
        let mut bin = vec![0x00, 0x3c, 0x00, 0xc0];
        bin.extend_from_slice(&(-1i32).to_le_bytes());
        let c = convert(&model, &bin, "test").unwrap();
        assert_eq!(c.graph.inputs, vec![GraphInput { name: "x".into(), shape: vec![1, 2] }]);
        assert_eq!(c.floats.len(), 1);
        assert_eq!(c.floats[0].dtype, safetensors::Dtype::F16);
        assert_eq!(c.graph.nodes[2].int_value, Some(IntConst { shape: vec![], values: vec![-1] }));
        let leaky = &c.graph.nodes[4];
        assert_eq!(leaky.attrs["alpha"], Attr::Float(0.1));
        assert_eq!(leaky.attrs["padding"], Attr::Str("VALID".into()));
        assert_eq!(leaky.attrs["strides"], Attr::Ints(vec![1, 2]));
        assert_eq!(c.graph.outputs, vec!["Identity".to_string()]);
        // A shard of the wrong length is an error naming the sizes.
        let e = convert(&model, &bin[..6], "test").unwrap_err().to_string();
        assert!(e.contains("weights end inside axis"), "{e}");
    }
}

//! A small dataflow-graph format and its interpreter in candle, for models
//! that ship as TensorFlow graphs (NanoDet in the TFJS graph-model format).
//!
//! The converter ([`crate::tfjs`]) writes the topology as JSON ([`GraphDef`])
//! and the float constants as safetensors; integer constants (shapes, axes,
//! permutations, paddings) live inline in the JSON. [`Graph::load`] compiles
//! the topology once (topological order, constant folding of the filters into
//! candle's OIHW layout, last-use tracking so intermediate tensors are freed
//! early) and [`Graph::run`] evaluates it on a batch.
//!
//! Supported ops (TensorFlow semantics): Placeholder, Const, Identity,
//! Conv2D (NHWC, VALID, HWIO filters, groups from the channel ratio), Add,
//! AddV2, LeakyRelu, Pad, PadV2, Transpose, ConcatV2, ResizeBilinear
//! (half-pixel centres), SplitV, Sigmoid, Reshape, MaxPool (NHWC, VALID) and
//! SparseToDense. The graph's Reshape targets were exported for batch 1; a
//! leading 1 in a Reshape target is read as the batch size.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use std::sync::Arc;

use candle_core::{DType, Device, Module, Tensor};

use crate::conv::{Activation, FusedConv};
use serde::{Deserialize, Serialize};

pub const GRAPH_FORMAT: &str = "vlnav-graph/1";

/// An attribute value of a node.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Attr {
    Bool(bool),
    Int(i64),
    Float(f64),
    Ints(Vec<i64>),
    Str(String),
}

/// An integer constant stored inline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IntConst {
    pub shape: Vec<usize>,
    pub values: Vec<i64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeDef {
    pub name: String,
    pub op: String,
    #[serde(default)]
    pub inputs: Vec<String>,
    #[serde(default)]
    pub attrs: BTreeMap<String, Attr>,
    /// For integer Const nodes: the value. Float Const nodes are in the weights file under `name`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub int_value: Option<IntConst>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GraphInput {
    pub name: String,
    pub shape: Vec<usize>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GraphDef {
    pub format: String,
    /// Where the graph came from (free text).
    pub source: String,
    pub inputs: Vec<GraphInput>,
    pub outputs: Vec<String>,
    pub nodes: Vec<NodeDef>,
}

#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error("graph: {0}")]
    Invalid(String),
    #[error("graph node {node} ({op}): {msg}")]
    Node { node: String, op: String, msg: String },
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

fn invalid(msg: impl Into<String>) -> GraphError {
    GraphError::Invalid(msg.into())
}

/// A value flowing along an edge.
#[derive(Clone, Debug)]
enum Value {
    Float(Tensor),
    Int(IntConst),
    Many(Vec<Tensor>),
}

/// Where an input comes from: a node slot and an output index.
#[derive(Clone, Copy, Debug)]
struct Src {
    node: usize,
    output: usize,
}

#[derive(Clone, Debug)]
struct Step {
    node: usize,
    op: Op,
    inputs: Vec<Src>,
}

#[derive(Clone, Debug)]
enum Op {
    Input(usize),
    Identity,
    /// `bias` is set when the following Add of a per-channel constant was fused
    /// in, `pad` when a zero Pad before it was, `act` when a LeakyRelu after it
    /// was; `fused` is the one-pass CPU kernel (ungrouped, undilated convolutions).
    Conv2d {
        filter: Tensor,
        bias: Option<Tensor>,
        stride: usize,
        dilation: usize,
        pad: usize,
        act: Activation,
        fused: Option<Arc<FusedConv>>,
    },
    Add,
    LeakyRelu(f64),
    Pad,
    PadConst,
    Transpose,
    Concat,
    ResizeBilinear,
    SplitV,
    Sigmoid,
    Reshape,
    MaxPool {
        k: usize,
        stride: usize,
    },
    SparseToDense,
}

/// A compiled graph on a device.
#[derive(Debug)]
pub struct Graph {
    names: Vec<String>,
    ops: Vec<String>,
    consts: HashMap<usize, Value>,
    steps: Vec<Step>,
    /// For each node, the index of the last step reading it (outputs: never freed).
    last_use: Vec<usize>,
    outputs: Vec<Src>,
    input_shapes: Vec<Vec<usize>>,
}

fn parse_src(s: &str, index: &HashMap<&str, usize>) -> Result<Src, GraphError> {
    let (name, output) = match s.rsplit_once(':') {
        Some((n, o)) if o.chars().all(|c| c.is_ascii_digit()) => {
            (n, o.parse().map_err(|_| invalid(format!("bad input reference {s}")))?)
        }
        _ => (s, 0),
    };
    let node = *index.get(name).ok_or_else(|| invalid(format!("unknown input {s}")))?;
    Ok(Src { node, output })
}

fn ints_attr(node: &NodeDef, key: &str) -> Result<Vec<i64>, GraphError> {
    match node.attrs.get(key) {
        Some(Attr::Ints(v)) => Ok(v.clone()),
        Some(Attr::Int(v)) => Ok(vec![*v]),
        _ => Err(node_err(node, format!("missing integer list attribute {key}"))),
    }
}

fn node_err(node: &NodeDef, msg: impl Into<String>) -> GraphError {
    GraphError::Node { node: node.name.clone(), op: node.op.clone(), msg: msg.into() }
}

fn check_nhwc_valid(node: &NodeDef) -> Result<(), GraphError> {
    if let Some(Attr::Str(f)) = node.attrs.get("data_format")
        && f != "NHWC"
    {
        return Err(node_err(node, format!("data_format {f} is not supported (NHWC only)")));
    }
    match node.attrs.get("padding") {
        Some(Attr::Str(p)) if p == "VALID" => Ok(()),
        other => Err(node_err(
            node,
            format!("padding {other:?} is not supported (VALID only; explicit Pad ops carry the padding)"),
        )),
    }
}

/// Same spatial value for H and W from an NHWC `[1, h, w, 1]` attribute.
fn spatial(node: &NodeDef, key: &str, default: i64) -> Result<usize, GraphError> {
    let v = match node.attrs.get(key) {
        None => return Ok(default as usize),
        Some(_) => ints_attr(node, key)?,
    };
    match v.as_slice() {
        [1, h, w, 1] if h == w && *h > 0 => Ok(*h as usize),
        [h, w] if h == w && *h > 0 => Ok(*h as usize),
        _ => Err(node_err(node, format!("{key} {v:?}: only equal H/W values in NHWC order are supported"))),
    }
}

impl Graph {
    /// Compiles `def` with float constants from the safetensors file `weights`.
    pub fn load(def: &GraphDef, weights: &Path, device: &Device) -> Result<Self, GraphError> {
        let tensors = candle_core::safetensors::load(weights, device)?;
        Self::compile(def, tensors, device)
    }

    /// Compiles `def` with float constants given by name.
    pub fn compile(def: &GraphDef, mut tensors: HashMap<String, Tensor>, device: &Device) -> Result<Self, GraphError> {
        if def.format != GRAPH_FORMAT {
            return Err(invalid(format!("format {:?}, expected {GRAPH_FORMAT:?}", def.format)));
        }
        let index: HashMap<&str, usize> = def.nodes.iter().enumerate().map(|(i, n)| (n.name.as_str(), i)).collect();
        if index.len() != def.nodes.len() {
            return Err(invalid("duplicate node names"));
        }
        let mut inputs_of: Vec<Vec<Src>> = Vec::with_capacity(def.nodes.len());
        for n in &def.nodes {
            let srcs = n
                .inputs
                .iter()
                .filter(|s| !s.starts_with('^'))
                .map(|s| parse_src(s, &index))
                .collect::<Result<Vec<_>, _>>()?;
            inputs_of.push(srcs);
        }
        // Topological order (Kahn), stable in file order.
        let n = def.nodes.len();
        let mut indegree: Vec<usize> = inputs_of.iter().map(|v| v.len()).collect();
        let mut consumers: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (i, srcs) in inputs_of.iter().enumerate() {
            for s in srcs {
                consumers[s.node].push(i);
            }
        }
        let mut ready: std::collections::VecDeque<usize> = (0..n).filter(|&i| indegree[i] == 0).collect();
        let mut order = Vec::with_capacity(n);
        while let Some(i) = ready.pop_front() {
            order.push(i);
            for &c in &consumers[i] {
                indegree[c] -= 1;
                if indegree[c] == 0 {
                    ready.push_back(c);
                }
            }
        }
        if order.len() != n {
            return Err(invalid("the graph has a cycle"));
        }

        let mut consts: HashMap<usize, Value> = HashMap::new();
        for (i, node) in def.nodes.iter().enumerate() {
            if node.op != "Const" {
                continue;
            }
            let value = match &node.int_value {
                Some(c) => {
                    if c.shape.iter().product::<usize>() != c.values.len() {
                        return Err(node_err(node, "integer constant: shape and value count differ"));
                    }
                    Value::Int(c.clone())
                }
                None => {
                    let t = tensors
                        .remove(&node.name)
                        .ok_or_else(|| node_err(node, "float constant missing from the weights file"))?;
                    Value::Float(t.to_dtype(DType::F32)?.to_device(device)?)
                }
            };
            consts.insert(i, value);
        }

        let input_names: Vec<&str> = def.inputs.iter().map(|i| i.name.as_str()).collect();
        let mut steps = Vec::new();
        for &i in &order {
            let node = &def.nodes[i];
            let srcs = inputs_of[i].clone();
            let op = match node.op.as_str() {
                "Const" => continue,
                "Placeholder" => Op::Input(
                    input_names
                        .iter()
                        .position(|n| *n == node.name)
                        .ok_or_else(|| node_err(node, "placeholder is not a declared graph input"))?,
                ),
                "Identity" => Op::Identity,
                "Add" | "AddV2" => Op::Add,
                "LeakyRelu" => match node.attrs.get("alpha") {
                    Some(Attr::Float(a)) => Op::LeakyRelu(*a),
                    Some(Attr::Int(a)) => Op::LeakyRelu(*a as f64),
                    None => Op::LeakyRelu(0.2),
                    other => return Err(node_err(node, format!("alpha {other:?}"))),
                },
                "Pad" => Op::Pad,
                "PadV2" => Op::PadConst,
                "Transpose" => Op::Transpose,
                "ConcatV2" => Op::Concat,
                "SplitV" => Op::SplitV,
                "Sigmoid" => Op::Sigmoid,
                "Reshape" => Op::Reshape,
                "SparseToDense" => Op::SparseToDense,
                "ResizeBilinear" => {
                    let half = matches!(node.attrs.get("half_pixel_centers"), Some(Attr::Bool(true)));
                    let corners = matches!(node.attrs.get("align_corners"), Some(Attr::Bool(true)));
                    if !half || corners {
                        return Err(node_err(node, "only half-pixel-centre bilinear resizing is supported"));
                    }
                    Op::ResizeBilinear
                }
                "MaxPool" => {
                    check_nhwc_valid(node)?;
                    Op::MaxPool { k: spatial(node, "ksize", 1)?, stride: spatial(node, "strides", 1)? }
                }
                "Conv2D" => {
                    check_nhwc_valid(node)?;
                    let stride = spatial(node, "strides", 1)?;
                    let dilation = spatial(node, "dilations", 1)?;
                    let filter_src = srcs.get(1).ok_or_else(|| node_err(node, "needs a filter input"))?;
                    let filter = match consts.get(&filter_src.node) {
                        Some(Value::Float(t)) if t.rank() == 4 => t.permute((3, 2, 0, 1))?.contiguous()?,
                        _ => return Err(node_err(node, "the filter must be a rank-4 float constant")),
                    };
                    Op::Conv2d { filter, bias: None, stride, dilation, pad: 0, act: Activation::Identity, fused: None }
                }
                other => return Err(node_err(node, format!("op {other} is not supported"))),
            };
            steps.push(Step { node: i, op, inputs: srcs });
        }

        let outputs = def.outputs.iter().map(|o| parse_src(o, &index)).collect::<Result<Vec<_>, _>>()?;
        fuse_conv_bias(&mut steps, &consts, &consumers, &outputs)?;
        fold_pads(&mut steps, &consts, &consumers, &outputs)?;
        fuse_leaky_relu(&mut steps, &consumers, &outputs);
        for step in &mut steps {
            if let Op::Conv2d { filter, bias, stride, dilation: 1, pad, act, fused } = &mut step.op {
                let b = bias.as_ref().map(|b| b.flatten_all()).transpose()?;
                *fused = Some(Arc::new(FusedConv::new(filter, b.as_ref(), *stride, *pad, *act)?));
            }
        }
        let mut last_use = vec![0usize; n];
        for (si, step) in steps.iter().enumerate() {
            for s in &step.inputs {
                last_use[s.node] = si;
            }
        }
        for o in &outputs {
            last_use[o.node] = usize::MAX;
        }
        Ok(Self {
            names: def.nodes.iter().map(|n| n.name.clone()).collect(),
            ops: def.nodes.iter().map(|n| n.op.clone()).collect(),
            consts,
            steps,
            last_use,
            outputs,
            input_shapes: def.inputs.iter().map(|i| i.shape.clone()).collect(),
        })
    }

    /// Declared input shapes (batch included as exported).
    pub fn input_shapes(&self) -> &[Vec<usize>] {
        &self.input_shapes
    }

    /// Evaluates the graph; returns the declared outputs in order.
    pub fn run(&self, inputs: &[Tensor]) -> Result<Vec<Tensor>, GraphError> {
        if inputs.len() != self.input_shapes.len() {
            return Err(invalid(format!("expected {} inputs, got {}", self.input_shapes.len(), inputs.len())));
        }
        let batch = inputs.first().map(|t| t.dims().first().copied().unwrap_or(1)).unwrap_or(1);
        let mut values: Vec<Option<Value>> = vec![None; self.names.len()];
        for (si, step) in self.steps.iter().enumerate() {
            let args: Vec<Value> = step.inputs.iter().map(|s| self.fetch(&values, *s)).collect::<Result<_, _>>()?;
            let out = self.eval(step, &args, inputs, batch).map_err(|e| match e {
                GraphError::Candle(c) => GraphError::Node {
                    node: self.names[step.node].clone(),
                    op: self.ops[step.node].clone(),
                    msg: c.to_string(),
                },
                other => other,
            })?;
            values[step.node] = Some(out);
            for s in &step.inputs {
                if self.last_use[s.node] == si {
                    values[s.node] = None;
                }
            }
        }
        self.outputs
            .iter()
            .map(|s| match self.fetch(&values, *s)? {
                Value::Float(t) => Ok(t),
                _ => Err(invalid(format!("output {} is not a float tensor", self.names[s.node]))),
            })
            .collect()
    }

    fn fetch(&self, values: &[Option<Value>], s: Src) -> Result<Value, GraphError> {
        let v = match self.consts.get(&s.node) {
            Some(c) => c.clone(),
            None => values[s.node]
                .clone()
                .ok_or_else(|| invalid(format!("value of {} used before it was computed", self.names[s.node])))?,
        };
        match (v, s.output) {
            (Value::Many(mut ts), o) => {
                if o >= ts.len() {
                    return Err(invalid(format!("{} has no output {o}", self.names[s.node])));
                }
                Ok(Value::Float(ts.swap_remove(o)))
            }
            (v, 0) => Ok(v),
            (_, o) => Err(invalid(format!("{} has no output {o}", self.names[s.node]))),
        }
    }

    fn eval(&self, step: &Step, args: &[Value], inputs: &[Tensor], batch: usize) -> Result<Value, GraphError> {
        let node = &self.names[step.node];
        let err = |msg: String| GraphError::Node { node: node.clone(), op: self.ops[step.node].clone(), msg };
        let float = |i: usize| -> Result<&Tensor, GraphError> {
            match args.get(i) {
                Some(Value::Float(t)) => Ok(t),
                _ => Err(err(format!("input {i} must be a float tensor"))),
            }
        };
        let int = |i: usize| -> Result<&IntConst, GraphError> {
            match args.get(i) {
                Some(Value::Int(c)) => Ok(c),
                _ => Err(err(format!("input {i} must be an integer constant"))),
            }
        };
        let axis = |a: i64, rank: usize| -> Result<usize, GraphError> {
            let r = rank as i64;
            if a < -r || a >= r {
                return Err(err(format!("axis {a} out of range for rank {rank}")));
            }
            Ok(((a + r) % r) as usize)
        };
        Ok(match &step.op {
            Op::Input(i) => Value::Float(inputs[*i].clone()),
            Op::Identity => args.first().cloned().ok_or_else(|| err("no input".into()))?,
            Op::Add => match (&args[0], &args[1]) {
                (Value::Float(a), Value::Float(b)) => Value::Float(a.broadcast_add(b)?),
                (Value::Int(a), Value::Int(b)) => {
                    if a.shape != b.shape {
                        return Err(err("integer Add needs equal shapes".into()));
                    }
                    let values = a.values.iter().zip(&b.values).map(|(x, y)| x + y).collect();
                    Value::Int(IntConst { shape: a.shape.clone(), values })
                }
                _ => return Err(err("mixed float and integer Add".into())),
            },
            Op::LeakyRelu(alpha) => {
                let x = float(0)?;
                Value::Float(x.maximum(&(x * *alpha)?)?)
            }
            Op::Pad | Op::PadConst => {
                let x = float(0)?;
                let p = int(1)?;
                if p.shape != [x.rank(), 2] {
                    return Err(err(format!("paddings shape {:?} for rank {}", p.shape, x.rank())));
                }
                let fill = if matches!(step.op, Op::PadConst) {
                    let c = float(2)?;
                    c.flatten_all()?.to_vec1::<f32>()?.first().copied().unwrap_or(0.0)
                } else {
                    0.0
                };
                let mut y = x.clone();
                for d in 0..x.rank() {
                    let (l, r) = (p.values[2 * d], p.values[2 * d + 1]);
                    if l < 0 || r < 0 {
                        return Err(err("negative padding".into()));
                    }
                    y = pad_const(&y, d, l as usize, r as usize, fill)?;
                }
                Value::Float(y)
            }
            Op::Transpose => {
                let x = float(0)?;
                let perm: Vec<usize> = int(1)?.values.iter().map(|&v| v as usize).collect();
                if perm.len() != x.rank() {
                    return Err(err(format!("permutation {perm:?} for rank {}", x.rank())));
                }
                Value::Float(x.permute(perm)?)
            }
            Op::Conv2d { filter, bias, stride, dilation, pad, act, fused } => {
                let x = float(0)?;
                let nchw = x.permute((0, 3, 1, 2))?;
                let cin = nchw.dim(1)?;
                let fin = filter.dim(1)?;
                if fin == 0 || cin % fin != 0 {
                    return Err(err(format!("input has {cin} channels, filter expects {fin}")));
                }
                let y = match fused {
                    Some(f) if cin == fin => f.forward(&nchw)?,
                    _ => {
                        let mut y = nchw.conv2d(filter, *pad, *stride, *dilation, cin / fin)?;
                        if let Some(b) = bias {
                            y = y.broadcast_add(b)?;
                        }
                        match act {
                            Activation::Leaky(a) => y.maximum(&(&y * *a as f64)?)?,
                            _ => y,
                        }
                    }
                };
                Value::Float(y.permute((0, 2, 3, 1))?)
            }
            Op::MaxPool { k, stride } => {
                let x = float(0)?;
                let y = x.permute((0, 3, 1, 2))?.contiguous()?.max_pool2d_with_stride(*k, *stride)?;
                Value::Float(y.permute((0, 2, 3, 1))?)
            }
            Op::Concat => {
                let last = args.len() - 1;
                let a = int(last)?.values.first().copied().ok_or_else(|| err("empty axis".into()))?;
                let ts: Vec<&Tensor> = (0..last).map(float).collect::<Result<_, _>>()?;
                let rank = ts.first().map(|t| t.rank()).ok_or_else(|| err("nothing to concatenate".into()))?;
                Value::Float(Tensor::cat(&ts, axis(a, rank)?)?)
            }
            Op::ResizeBilinear => {
                let x = float(0)?;
                let size = &int(1)?.values;
                if size.len() != 2 || size[0] <= 0 || size[1] <= 0 {
                    return Err(err(format!("size {size:?}")));
                }
                let y = x.permute((0, 3, 1, 2))?.contiguous()?.upsample_bilinear2d(
                    size[0] as usize,
                    size[1] as usize,
                    false,
                )?;
                Value::Float(y.permute((0, 2, 3, 1))?)
            }
            Op::SplitV => {
                let x = float(0)?;
                let sizes = &int(1)?.values;
                let d = axis(int(2)?.values.first().copied().unwrap_or(0), x.rank())?;
                let total = x.dim(d)? as i64;
                let known: i64 = sizes.iter().filter(|&&s| s >= 0).sum();
                let mut start = 0usize;
                let mut parts = Vec::with_capacity(sizes.len());
                for &s in sizes {
                    let len = if s < 0 { total - known } else { s };
                    if len < 0 || start as i64 + len > total {
                        return Err(err(format!("split sizes {sizes:?} do not fit dimension {total}")));
                    }
                    parts.push(x.narrow(d, start, len as usize)?);
                    start += len as usize;
                }
                Value::Many(parts)
            }
            Op::Sigmoid => Value::Float(candle_nn::ops::sigmoid(&float(0)?.contiguous()?)?),
            Op::Reshape => {
                let x = float(0)?;
                let mut target = int(1)?.values.clone();
                if batch > 1 && target.first() == Some(&1) && x.dims().first() == Some(&batch) {
                    target[0] = batch as i64;
                }
                let count = x.elem_count() as i64;
                let known: i64 = target.iter().filter(|&&v| v != -1).product();
                let shape: Vec<usize> = target
                    .iter()
                    .map(|&v| if v == -1 { (count / known.max(1)) as usize } else { v as usize })
                    .collect();
                if shape.iter().product::<usize>() as i64 != count {
                    return Err(err(format!("cannot reshape {:?} to {target:?}", x.dims())));
                }
                Value::Float(x.contiguous()?.reshape(shape)?)
            }
            Op::SparseToDense => {
                let indices = int(0)?;
                let shape: Vec<usize> = int(1)?.values.iter().map(|&v| v.max(0) as usize).collect();
                let values = int(2)?;
                let default = int(3)?.values.first().copied().unwrap_or(0);
                let numel: usize = shape.iter().product();
                let mut out = vec![default; numel];
                let rank = shape.len().max(1);
                let count = if indices.values.is_empty() { 0 } else { indices.values.len() / rank };
                for k in 0..count {
                    let mut flat = 0usize;
                    for (d, &dim) in shape.iter().enumerate() {
                        let idx = indices.values[k * rank + d];
                        if idx < 0 || idx as usize >= dim {
                            return Err(err(format!("index {idx} out of range")));
                        }
                        flat = flat * dim + idx as usize;
                    }
                    let v = if values.values.len() == 1 { values.values[0] } else { values.values[k] };
                    out[flat] = v;
                }
                Value::Int(IntConst { shape, values: out })
            }
        })
    }
}

/// Folds `Add(Conv2D(x), c)` with a per-channel constant `c` into the
/// convolution, so the bias is added in the convolution's own (contiguous
/// NCHW) layout instead of through the NHWC view; the Add becomes an Identity.
fn fuse_conv_bias(
    steps: &mut [Step],
    consts: &HashMap<usize, Value>,
    consumers: &[Vec<usize>],
    outputs: &[Src],
) -> Result<(), GraphError> {
    let step_of: HashMap<usize, usize> = steps.iter().enumerate().map(|(i, s)| (s.node, i)).collect();
    for i in 0..steps.len() {
        if !matches!(steps[i].op, Op::Add) || steps[i].inputs.len() != 2 {
            continue;
        }
        let (conv_src, bias_src) = (steps[i].inputs[0], steps[i].inputs[1]);
        let Some(&ci) = step_of.get(&conv_src.node) else { continue };
        let sole_use = consumers[conv_src.node].len() == 1 && outputs.iter().all(|o| o.node != conv_src.node);
        let Some(Value::Float(bias)) = consts.get(&bias_src.node) else { continue };
        let Op::Conv2d { filter, bias: existing, .. } = &steps[ci].op else { continue };
        if !sole_use || existing.is_some() || bias.rank() != 1 || bias.dim(0)? != filter.dim(0)? {
            continue;
        }
        let b = bias.reshape((1, bias.dim(0)?, 1, 1))?;
        if let Op::Conv2d { bias, .. } = &mut steps[ci].op {
            *bias = Some(b);
        }
        steps[i].op = Op::Identity;
        steps[i].inputs.truncate(1);
    }
    Ok(())
}

/// Follows `node`'s value forward through Identity and Transpose steps, each
/// the sole reader of the previous value and no graph output; returns the
/// step reading the end of the chain and the permutation the chain applies
/// (`perm[d]`: which dimension of `node`'s value is dimension d at the end).
fn chain_forward(
    steps: &[Step],
    step_of: &HashMap<usize, usize>,
    consts: &HashMap<usize, Value>,
    consumers: &[Vec<usize>],
    outputs: &[Src],
    node: usize,
) -> Option<(usize, Vec<usize>)> {
    let mut perm: Vec<usize> = (0..4).collect();
    let mut at = node;
    loop {
        if consumers[at].len() != 1 || outputs.iter().any(|o| o.node == at) {
            return None;
        }
        let next = *step_of.get(&consumers[at][0])?;
        match &steps[next].op {
            Op::Identity => {}
            Op::Transpose => {
                let Some(Value::Int(p)) = steps[next].inputs.get(1).and_then(|s| consts.get(&s.node)) else {
                    return None;
                };
                if p.values.len() != 4 {
                    return None;
                }
                perm = p.values.iter().map(|&v| perm.get(v as usize).copied()).collect::<Option<Vec<_>>>()?;
            }
            _ => return Some((next, perm)),
        }
        at = steps[next].node;
    }
}

/// Folds `Pad` ops that only add equal zero borders to the height and width
/// of a convolution's input (through transposes) into the convolution's
/// padding: the padded copy of the activation is never made.
fn fold_pads(
    steps: &mut [Step],
    consts: &HashMap<usize, Value>,
    consumers: &[Vec<usize>],
    outputs: &[Src],
) -> Result<(), GraphError> {
    let step_of: HashMap<usize, usize> = steps.iter().enumerate().map(|(i, s)| (s.node, i)).collect();
    for i in 0..steps.len() {
        if !matches!(steps[i].op, Op::Pad) || steps[i].inputs.len() != 2 {
            continue;
        }
        let Some(Value::Int(p)) = consts.get(&steps[i].inputs[1].node) else { continue };
        if p.shape != [4, 2] {
            continue;
        }
        let Some((ci, perm)) = chain_forward(steps, &step_of, consts, consumers, outputs, steps[i].node) else {
            continue;
        };
        // The convolution reads NHWC: its dims 1 and 2 are the pad's dims perm[1] and perm[2].
        let amount = |d: usize| (p.values[2 * perm[d]], p.values[2 * perm[d] + 1]);
        let (h, w) = (amount(1), amount(2));
        let symmetric = h.0 == h.1 && w == h && h.0 > 0;
        if !symmetric || amount(0) != (0, 0) || amount(3) != (0, 0) {
            continue;
        }
        let Op::Conv2d { pad, dilation: 1, .. } = &mut steps[ci].op else { continue };
        *pad += h.0 as usize;
        steps[i].op = Op::Identity;
        steps[i].inputs.truncate(1);
    }
    Ok(())
}

/// Fuses a LeakyRelu into the convolution whose output it reads (through
/// the bias Add and transposes, each read by nothing else): the activation is
/// applied in place as the convolution's output is produced.
fn fuse_leaky_relu(steps: &mut [Step], consumers: &[Vec<usize>], outputs: &[Src]) {
    let step_of: HashMap<usize, usize> = steps.iter().enumerate().map(|(i, s)| (s.node, i)).collect();
    for ci in 0..steps.len() {
        if !matches!(steps[ci].op, Op::Conv2d { act: Activation::Identity, .. }) {
            continue;
        }
        // Transposes are only followed (their permutation does not matter to an elementwise op).
        let Some(li) = chain_forward_any(steps, &step_of, consumers, outputs, steps[ci].node) else {
            continue;
        };
        let Op::LeakyRelu(alpha) = steps[li].op else { continue };
        if let Op::Conv2d { act, .. } = &mut steps[ci].op {
            *act = Activation::Leaky(alpha as f32);
        }
        steps[li].op = Op::Identity;
    }
}

/// [`chain_forward`] without reading permutations.
fn chain_forward_any(
    steps: &[Step],
    step_of: &HashMap<usize, usize>,
    consumers: &[Vec<usize>],
    outputs: &[Src],
    node: usize,
) -> Option<usize> {
    let mut at = node;
    loop {
        if consumers[at].len() != 1 || outputs.iter().any(|o| o.node == at) {
            return None;
        }
        let next = *step_of.get(&consumers[at][0])?;
        match &steps[next].op {
            Op::Identity | Op::Transpose => at = steps[next].node,
            _ => return Some(next),
        }
    }
}

/// Pads dimension `dim` of `x` with `left`/`right` copies of `value`.
fn pad_const(x: &Tensor, dim: usize, left: usize, right: usize, value: f32) -> candle_core::Result<Tensor> {
    if left == 0 && right == 0 {
        return Ok(x.clone());
    }
    if value == 0.0 {
        return x.pad_with_zeros(dim, left, right);
    }
    let mut parts = Vec::with_capacity(3);
    let mut shape = x.dims().to_vec();
    if left > 0 {
        shape[dim] = left;
        parts.push(Tensor::full(value, shape.clone(), x.device())?.to_dtype(x.dtype())?);
    }
    parts.push(x.clone());
    if right > 0 {
        shape[dim] = right;
        parts.push(Tensor::full(value, shape, x.device())?.to_dtype(x.dtype())?);
    }
    Tensor::cat(&parts, dim)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(name: &str, op: &str, inputs: &[&str]) -> NodeDef {
        NodeDef {
            name: name.into(),
            op: op.into(),
            inputs: inputs.iter().map(|s| s.to_string()).collect(),
            attrs: BTreeMap::new(),
            int_value: None,
        }
    }

    fn int_const(name: &str, shape: &[usize], values: &[i64]) -> NodeDef {
        NodeDef {
            int_value: Some(IntConst { shape: shape.to_vec(), values: values.to_vec() }),
            ..node(name, "Const", &[])
        }
    }

    /// x (NCHW 1×1×3×3) → pad 1 → NHWC → conv 3×3 (sum filter) + bias → NCHW → leaky relu.
    #[test]
    fn runs_a_padded_conv_with_tensorflow_semantics() {
        let dev = Device::Cpu;
        let mut conv = node("conv", "Conv2D", &["to_nhwc", "filter"]);
        conv.attrs.insert("padding".into(), Attr::Str("VALID".into()));
        conv.attrs.insert("data_format".into(), Attr::Str("NHWC".into()));
        conv.attrs.insert("strides".into(), Attr::Ints(vec![1, 1, 1, 1]));
        let mut leaky = node("leaky", "LeakyRelu", &["to_nchw"]);
        leaky.attrs.insert("alpha".into(), Attr::Float(0.1));
        let def = GraphDef {
            format: GRAPH_FORMAT.into(),
            source: "test".into(),
            inputs: vec![GraphInput { name: "x".into(), shape: vec![1, 1, 3, 3] }],
            outputs: vec!["out".into()],
            nodes: vec![
                node("out", "Identity", &["leaky"]), // out of order on purpose
                node("x", "Placeholder", &[]),
                int_const("pads", &[4, 2], &[0, 0, 0, 0, 1, 1, 1, 1]),
                node("pad", "Pad", &["x", "pads"]),
                int_const("perm_nhwc", &[4], &[0, 2, 3, 1]),
                node("to_nhwc", "Transpose", &["pad", "perm_nhwc"]),
                node("filter", "Const", &[]),
                conv,
                node("bias", "Const", &[]),
                node("add", "Add", &["conv", "bias"]),
                int_const("perm_nchw", &[4], &[0, 3, 1, 2]),
                node("to_nchw", "Transpose", &["add", "perm_nchw"]),
                leaky,
            ],
        };
        let mut w = HashMap::new();
        w.insert("filter".to_string(), Tensor::ones((3, 3, 1, 1), DType::F32, &dev).unwrap());
        w.insert("bias".to_string(), Tensor::new(&[-4.0f32], &dev).unwrap());
        let g = Graph::compile(&def, w, &dev).unwrap();
        let x = Tensor::ones((1, 1, 3, 3), DType::F32, &dev).unwrap();
        let y = g.run(&[x]).unwrap().remove(0);
        assert_eq!(y.dims(), &[1, 1, 3, 3]);
        // Corner: 4 ones − 4 = 0; edge: 6 − 4 = 2; centre: 9 − 4 = 5.
        let v: Vec<f32> = y.flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(v, vec![0.0, 2.0, 0.0, 2.0, 5.0, 2.0, 0.0, 2.0, 0.0]);

        // A missing weight or an unknown op is rejected, naming it.
        let e = Graph::compile(&def, HashMap::new(), &dev).unwrap_err().to_string();
        assert!(e.contains("filter") && e.contains("missing"), "{e}");
        let mut bad = def.clone();
        bad.nodes.push(node("weird", "Einsum", &["x"]));
        let mut w = HashMap::new();
        w.insert("filter".to_string(), Tensor::ones((3, 3, 1, 1), DType::F32, &dev).unwrap());
        w.insert("bias".to_string(), Tensor::new(&[-4.0f32], &dev).unwrap());
        let e = Graph::compile(&bad, w, &dev).unwrap_err().to_string();
        assert!(e.contains("Einsum"), "{e}");
    }

    #[test]
    fn split_sigmoid_reshape_and_negative_padding_value() {
        let dev = Device::Cpu;
        let mut pool = node("pool", "MaxPool", &["padded"]);
        pool.attrs.insert("padding".into(), Attr::Str("VALID".into()));
        pool.attrs.insert("ksize".into(), Attr::Ints(vec![1, 3, 3, 1]));
        pool.attrs.insert("strides".into(), Attr::Ints(vec![1, 2, 2, 1]));
        let def = GraphDef {
            format: GRAPH_FORMAT.into(),
            source: "test".into(),
            inputs: vec![GraphInput { name: "x".into(), shape: vec![1, 4, 4, 1] }],
            outputs: vec!["split:1".into(), "sig".into(), "pool".into()],
            nodes: vec![
                node("x", "Placeholder", &[]),
                int_const("sizes", &[2], &[1, -1]),
                int_const("dim", &[], &[1]),
                node("split", "SplitV", &["x", "sizes", "dim"]),
                int_const("shape", &[2], &[1, -1]),
                node("flat", "Reshape", &["split", "shape"]),
                node("sig", "Sigmoid", &["flat"]),
                int_const("pads", &[4, 2], &[0, 0, 1, 0, 1, 0, 0, 0]),
                node("ninf", "Const", &[]),
                node("padded", "PadV2", &["x", "pads", "ninf"]),
                pool,
            ],
        };
        let mut w = HashMap::new();
        w.insert("ninf".to_string(), Tensor::new(f32::NEG_INFINITY, &dev).unwrap());
        let g = Graph::compile(&def, w, &dev).unwrap();
        let x = Tensor::arange(-8.0f32, 8.0, &dev).unwrap().reshape((1, 4, 4, 1)).unwrap();
        let out = g.run(&[x]).unwrap();
        assert_eq!(out[0].dims(), &[1, 3, 4, 1]);
        let s: Vec<f32> = out[1].flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(s.len(), 4);
        assert!((s[0] - 1.0 / (1.0 + 8f32.exp())).abs() < 1e-6);
        // −inf padding never wins the max: 5×5 padded input, 3×3/2 windows → 2×2.
        let p: Vec<f32> = out[2].flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(p, vec![-3.0, -1.0, 5.0, 7.0]);
    }
}

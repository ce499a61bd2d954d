"""ONNX operators our exports may contain, each supported by TensorRT's ONNX parser (8.6, 10.x).

The list is deliberately short: it is what the zoo needs. A test exports every variant and
checks its graph against it, so a change that introduces another operator fails until the op
is verified in TensorRT's operator support matrix and added here (and to export/CONTRACT.md).
"""

TENSORRT_SUPPORTED_OPS = frozenset(
    {
        "Add",
        "Cast",
        "Concat",
        "Conv",
        "ConvTranspose",
        "DepthToSpace",  # -hr prototypes: pixel shuffle (CRD mode)
        "Div",
        "Erf",  # MSNET: exact GELU
        "Exp",
        "Gemm",  # MSNET: Linear on 2-D activations
        "LayerNormalization",  # MSNET (opset 17; TensorRT >= 8.6 parses it natively)
        "LeakyRelu",
        "MatMul",  # MSNET: projections, q @ k^T, attn @ v
        "MaxPool",
        "Mul",
        "ReduceMax",  # MSNET: channel / spatial attention pooling
        "ReduceMean",
        "Reshape",
        "Resize",
        "Sigmoid",
        "Slice",
        "Softmax",
        "Split",
        "Sub",
        "Transpose",
    }
)

# Extra shape arithmetic of ``--dynamic`` exports (anchor grids from the input size): shape
# tensors computed from the input's shape, never from its values; all parsed by TensorRT.
DYNAMIC_SHAPE_OPS = frozenset(
    {"ConstantOfShape", "Expand", "Gather", "Range", "Shape", "Unsqueeze", "Cast", "Tile"}
)  # Tile: MSNET's class queries and position embeddings repeated to the batch size

# Operators whose output shape depends on tensor values: never allowed in raw exports (runtimes
# pre-allocate outputs); end-to-end exports contain NonMaxSuppression and TopK (below).
DATA_DEPENDENT_OPS = frozenset({"NonZero", "NonMaxSuppression", "TopK", "Unique", "Loop", "If"})

# The post-processing sub-graph of end-to-end exports (slimseg.deploy.end2end_graph), all in
# TensorRT's ONNX parser from 8.6 (NonMaxSuppression: data-dependent output, TensorRT >= 8.6).
END2END_OPS = frozenset(
    {
        "And", "ArgMax", "Cast", "Concat", "Div", "Equal", "Gather", "GatherElements",
        "GatherND", "Greater", "GreaterOrEqual", "Identity", "LessOrEqual", "MatMul", "Min",
        "Mul", "NonMaxSuppression", "Pad", "Range", "ReduceMax", "ReduceSum", "Reshape",
        "ScatterND", "Shape", "Sigmoid", "Slice", "Squeeze", "Sub", "TopK", "Transpose",
        "Unsqueeze", "Where", "Add",
    }
)  # fmt: skip

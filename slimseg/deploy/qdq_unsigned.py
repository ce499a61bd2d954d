"""An INT8 file's signed activation Q/DQ pairs as their unsigned equivalent (for OpenVINO).

``QuantizeLinear(x, s, z)`` with an int8 zero point ``z`` gives ``clamp(round(x / s) + z,
-128, 127)``; with the uint8 zero point ``z + 128`` it gives that value plus 128, clamped to
``[0, 255]``, and ``DequantizeLinear`` maps both to the same real number ``(q - z) * s``: the
same grid, the same rounding and the same clamp. The rewritten graph computes exactly what the
file says; only the integer type of the activations changes (weights stay int8).

Why: OpenVINO 2026.4's CPU plugin computes a signed int8 activation Q/DQ pair that feeds a
``Concat`` requantized at another scale wrongly (a ``tensorrt``-target file's C2f blocks): 10 %
relative error on an eight-node graph and 0 of ~70 candidate detections kept on the demo's
model, on every x86 ISA selectable from AVX2 to AVX512-VNNI (``ONEDNN_MAX_CPU_ISA``), while the
same graph with uint8 zero points is exact (docs/engines.md "INT8 in OpenVINO"). TensorRT takes
only the signed form (symmetric int8), so the file keeps it and the OpenVINO session rewrites
its in-memory copy (:class:`~slimseg.deploy.ov_session.OpenVinoSession`).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import numpy_helper

_QDQ = ("QuantizeLinear", "DequantizeLinear")
SUFFIX = "_as_uint8"  # the name of a zero point's unsigned twin


def unsigned_activations(proto: onnx.ModelProto) -> int:
    """Rewrite, in place, every activation ``QuantizeLinear`` / ``DequantizeLinear`` of
    ``proto`` whose zero point is an int8 initializer to use its uint8 twin (``z + 128``);
    ``DequantizeLinear`` of an initializer (quantized weights) keeps int8. Returns how many
    nodes changed (0: nothing signed, or no INT8 at all)."""
    graph = proto.graph
    inits = {t.name: t for t in graph.initializer}
    changed = 0
    retyped: set[str] = set()  # Q outputs now uint8
    for node in graph.node:
        if node.op_type not in _QDQ or len(node.input) < 3 or node.input[2] not in inits:
            continue
        if node.op_type == "DequantizeLinear" and node.input[0] in inits:
            continue  # weights: the integer type the convolution's kernel takes
        zp = numpy_helper.to_array(inits[node.input[2]])
        if zp.dtype != np.int8:
            continue
        twin = node.input[2] + SUFFIX
        if twin not in inits:
            arr = (zp.astype(np.int16) + 128).astype(np.uint8)
            inits[twin] = numpy_helper.from_array(arr, twin)
            graph.initializer.append(inits[twin])
        node.input[2] = twin
        changed += 1
        if node.op_type == "QuantizeLinear":
            retyped.add(node.output[0])
    kept = [v for v in graph.value_info if v.name not in retyped]  # their int8 types are stale
    del graph.value_info[:]
    graph.value_info.extend(kept)
    return changed

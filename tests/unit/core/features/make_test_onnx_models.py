"""Writes the tiny ONNX models the onnx feature encoder's tests load (python3-onnx).

Usage: make_test_onnx_models.py OUT_DIR

tiny_pyramid.onnx: input "image" [1, 3, 32, 32] -> three feature maps, listed in the graph in a
scrambled order (mid, fine, coarse) so the tests check that the encoder orders them by size:
  fine_feats   [1, 2, 16, 16] = conv1x1(avgpool2(image))
  mid_feats    [1, 4, 8, 8]   = conv1x1(avgpool4(image))
  coarse_feats [1, 8, 4, 4]   = conv1x1(avgpool8(image))
Each conv1x1 maps input channel c % 3 to output channel c with weight c + 1 and bias 0.25 c, so
output channel c = (c + 1) * block mean of normalised input channel c % 3 + 0.25 c.
two_outputs.onnx: the same without coarse_feats (wrong output count).
flat_output.onnx: coarse_feats flattened to [1, 128] (wrong output shape).
Node names differ from output names on purpose.
"""
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def level(name, pool, channels):
    w = np.zeros((channels, 3, 1, 1), dtype=np.float32)
    for c in range(channels):
        w[c, c % 3, 0, 0] = c + 1
    b = np.array([0.25 * c for c in range(channels)], dtype=np.float32)
    inits = [numpy_helper.from_array(w, name + "_w"), numpy_helper.from_array(b, name + "_b")]
    nodes = [
        helper.make_node("AveragePool", ["image"], [name + "_pooled"], name="pool_" + name,
                         kernel_shape=[pool, pool], strides=[pool, pool]),
        helper.make_node("Conv", [name + "_pooled", name + "_w", name + "_b"], [name],
                         name="conv_" + name, kernel_shape=[1, 1]),
    ]
    return nodes, inits


def model(levels, flatten_coarse=False):
    nodes, inits, outputs = [], [], []
    for name, pool, channels in levels:
        n, i = level(name, pool, channels)
        nodes += n
        inits += i
        side = 32 // pool
        if flatten_coarse and name == "coarse_feats":
            nodes[-1].output[0] = "coarse_conv"
            nodes.append(helper.make_node("Flatten", ["coarse_conv"], [name], name="flatten",
                                          axis=1))
            outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT,
                                                         [1, channels * side * side]))
        else:
            outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT,
                                                         [1, channels, side, side]))
    graph = helper.make_graph(
        nodes, "fslam_test_encoder",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 32, 32])], outputs,
        initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 11)],
                          producer_name="fslam tests")
    m.ir_version = 6
    onnx.checker.check_model(m)
    return m


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    mid, fine, coarse = ("mid_feats", 4, 4), ("fine_feats", 2, 2), ("coarse_feats", 8, 8)
    onnx.save(model([mid, fine, coarse]), os.path.join(out, "tiny_pyramid.onnx"))
    onnx.save(model([mid, fine]), os.path.join(out, "two_outputs.onnx"))
    onnx.save(model([mid, fine, coarse], flatten_coarse=True),
              os.path.join(out, "flat_output.onnx"))


if __name__ == "__main__":
    main()

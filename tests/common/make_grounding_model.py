"""Writes a tiny ONNX model that follows the grounding-detector contract (docs/segmentation.md),
for tests of the plumbing only: whatever the image and text, it answers two boxes, one scoring
high on every token and one low.

    make_grounding_model.py OUT.onnx SIZE CX CY W H [CX CY W H]

SIZE: the square input image side; CX CY W H: the high-scoring box (normalised 0..1); the low box
defaults to the image's bottom-right quarter. Writes OUT.onnx and OUT.onnx.vocab.txt.
Both inputs are consumed (times zero), so that importers keep them.
"""
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def main():
    out, size = sys.argv[1], int(sys.argv[2])
    high = [float(x) for x in sys.argv[3:7]]
    low = [float(x) for x in sys.argv[7:11]] if len(sys.argv) >= 11 else [0.875, 0.875, 0.25, 0.25]
    boxes = np.array([high, low], dtype=np.float32).reshape(-1)  # [Q * 4], Q = 2
    logit = np.array([[4.0, -4.0]], dtype=np.float32)            # [1, Q]: sigmoid 0.98 and 0.02

    init = [
        numpy_helper.from_array(np.zeros((boxes.size, 3), np.float32), "w_boxes"),
        numpy_helper.from_array(boxes, "b_boxes"),
        numpy_helper.from_array(np.array([1, 2, 4], np.int64), "boxes_shape"),
        numpy_helper.from_array(logit.T.copy(), "w_logits"),
        numpy_helper.from_array(np.zeros(2, np.float32), "b_logits"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
    ]
    nodes = [
        # boxes [1, 2, 4] = 0 * mean colour + the constant boxes
        helper.make_node("GlobalAveragePool", ["image"], ["pooled"]),
        helper.make_node("Flatten", ["pooled"], ["pooled_flat"], axis=1),
        helper.make_node("Gemm", ["pooled_flat", "w_boxes", "b_boxes"], ["boxes_flat"], transB=1),
        helper.make_node("Reshape", ["boxes_flat", "boxes_shape"], ["boxes"]),
        # logits [1, 2, L] = ones over the L tokens times the per-box logit
        helper.make_node("Mul", ["tokens", "zero"], ["tokens_zero"]),
        helper.make_node("Add", ["tokens_zero", "one"], ["ones"]),
        helper.make_node("Transpose", ["ones"], ["ones_t"], perm=[1, 0]),
        helper.make_node("Gemm", ["ones_t", "w_logits", "b_logits"], ["logits_lq"], transB=1),
        helper.make_node("Transpose", ["logits_lq"], ["logits_ql"], perm=[1, 0]),
        helper.make_node("Unsqueeze", ["logits_ql"], ["logits"], axes=[0]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_grounding",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, size, size]),
         helper.make_tensor_value_info("tokens", TensorProto.FLOAT, [1, "L"])],
        [helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, 2, 4]),
         helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 2, "L"])],
        init)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 11)])
    model.ir_version = 6
    onnx.checker.check_model(model)
    onnx.save(model, out)
    with open(out + ".vocab.txt", "w") as vocab:
        vocab.write("[PAD]\n[UNK]\nthe\nleft\nright\npanel\n.\n")


if __name__ == "__main__":
    main()

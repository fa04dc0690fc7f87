"""Graph surgery on a model file (:mod:`neuralbrdf.onnx_contract`): what each tensor depends on
(:func:`input_dependencies`) and one output cut out as a model of its own (:func:`output_model`)."""

from __future__ import annotations

import onnx

from neuralbrdf.onnx_contract.schema import OUTPUT_F


def input_dependencies(graph: onnx.GraphProto) -> dict[str, frozenset[str]]:
    """For every tensor of ``graph``, the graph inputs it depends on (nodes visited in topological
    order); :class:`ValueError` for a cycle or a tensor nothing produces."""
    depends: dict[str, frozenset[str]] = {vi.name: frozenset([vi.name]) for vi in graph.input}
    for init in graph.initializer:
        depends[init.name] = frozenset()
    pending = list(graph.node)
    while pending:
        ready = [n for n in pending if all(not i or i in depends for i in n.input)]
        if not ready:
            raise ValueError("the graph has a cycle or reads a tensor nothing produces")
        for node in ready:
            inputs = frozenset().union(*(depends[i] for i in node.input if i))
            for name in node.output:
                depends[name] = inputs
        pending = [n for n in pending if n not in ready]
    return depends


def output_model(proto: onnx.ModelProto, output: str) -> onnx.ModelProto:
    """The part of ``proto`` that computes ``output``, as a model whose only output is ``f`` (an
    ``Identity`` renames a fast path) and whose inputs are the graph inputs it reads: the nodes,
    initialisers and inputs ``output`` depends on, nothing else."""
    graph = proto.graph
    producer = {name: node for node in graph.node for name in node.output}
    needed, pending, nodes = set(), [output], []
    while pending:
        name = pending.pop()
        if name in needed or not name:
            continue
        needed.add(name)
        node = producer.get(name)
        if node is not None and node not in nodes:
            nodes.append(node)
            pending.extend(node.input)
    nodes = [node for node in graph.node if node in nodes]  # graph order is topological
    (declared,) = [vi for vi in graph.output if vi.name == output]
    result = onnx.ValueInfoProto()
    result.CopyFrom(declared)
    if output != OUTPUT_F:
        nodes.append(onnx.helper.make_node("Identity", [output], [OUTPUT_F], name=f"{output}_as_f"))
        result.name = OUTPUT_F
    initializers = [init for init in graph.initializer if init.name in needed]
    inputs = [vi for vi in graph.input if vi.name in needed and vi.name not in {init.name for init in initializers}]
    cut = onnx.helper.make_graph(nodes, f"{graph.name}:{output}", inputs, [result], initializers)
    model = onnx.helper.make_model(cut, opset_imports=proto.opset_import)
    model.ir_version = proto.ir_version
    return model

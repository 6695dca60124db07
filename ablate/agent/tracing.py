"""A population's acting forward as one traced function (``torch.fx``): the swapped network's forward with every
layer's weight views and their reshapes read once, at the trace, and no module call per layer; the same
operations in the same order as the module (``stacking.Members`` checks it bit for bit at its first call).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import torch
from torch import fx, nn

if TYPE_CHECKING:
    from ablate.agent.stacking import _Stack


def attribute(name: str) -> str:
    return "_stacked_" + name.replace(".", "_")


class _Tracer(fx.Tracer):
    """Traces through every module, torch's own layers included, into one graph of torch calls."""

    def is_leaf_module(self, m: nn.Module, module_qualified_name: str) -> bool:
        return False


def trace(network: nn.Module, stack: _Stack) -> Callable | None:
    """``network``'s acting forward as one traced function, or ``None`` where fx cannot trace it. Every operation
    on weights alone that gives a view of ``flat`` (a transpose, an unsqueeze) is done here, once."""
    views = stack._acting_views()
    tracer = _Tracer()
    stack.tracer = tracer
    try:
        graph = tracer.trace(network)
    except Exception:  # control flow on values, a call fx cannot follow: the module runs as it is
        return None
    finally:
        stack.tracer = None
    constants: dict[fx.Node, torch.Tensor] = {}
    attributes: dict[str, torch.Tensor] = {}
    storage = stack.flat.untyped_storage().data_ptr()
    for node in list(graph.nodes):
        if node.op == "get_attr" and node.target.startswith("_stacked_"):
            name = next(n for n in stack.layout if attribute(n) == node.target)
            constants[node] = attributes[node.target] = views[name]
            continue
        if node.op not in ("call_method", "call_function") or not node.all_input_nodes:
            continue
        if not all(n in constants for n in node.all_input_nodes):
            continue
        args, kwargs = fx.node.map_arg((node.args, node.kwargs), lambda n: constants[n])
        value = (
            getattr(args[0], node.target)(*args[1:], **kwargs)
            if node.op == "call_method"
            else node.target(*args, **kwargs)
        )
        if not isinstance(value, torch.Tensor) or value.untyped_storage().data_ptr() != storage:
            continue  # a copy (a reshape that cannot view): computed at every call, as it would go stale
        target = f"_stacked_folded_{len(attributes)}"
        attributes[target] = constants[node] = value
        with graph.inserting_before(node):
            folded = graph.get_attr(target)
        constants[folded] = value
        node.replace_all_uses_with(folded)
        graph.erase_node(node)
    graph.eliminate_dead_code()
    module = fx.GraphModule(attributes, graph)
    for target in list(module._buffers):  # plain attributes: read without nn.Module's lookup
        module.__dict__[target] = module._buffers.pop(target)
    return module.forward

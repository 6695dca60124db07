"""A population's acting forward as one traced function (``torch.fx``): the swapped network's forward with every
layer's weight views and their reshapes read once, at the trace, and no module call per layer, specialised to the
acting batch's shape (``_specialise``): the same arithmetic in the same order as the module, which
``stacking.Members`` checks bit for bit after every trace or ``Traced.rebind``.
"""

from __future__ import annotations

import operator
from typing import TYPE_CHECKING, NamedTuple

import torch
import torch.nn.functional as F
from torch import fx, nn

if TYPE_CHECKING:
    from ablate.agent.stacking import _Stack


def attribute(name: str) -> str:
    return "_stacked_" + name.replace(".", "_")


class _Tracer(fx.Tracer):
    """Traces through every module, torch's own layers included, into one graph of torch calls."""

    def is_leaf_module(self, m: nn.Module, module_qualified_name: str) -> bool:
        return False


class _Acting(nn.Module):
    """(members, batch, *observation) in, (members, batch, actions) out: the members folded into the batch."""

    def __init__(self, network: nn.Module) -> None:
        super().__init__()
        self.network = network

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.network(x.flatten(0, 1)).unflatten(0, (x.shape[0], x.shape[1]))


class Traced:
    """A traced acting forward (call it on x) and how its weight attributes are made from ``flat``'s views, to make
    them again from another ``flat`` (``rebind``: members left) without tracing again."""

    def __init__(self, module: fx.GraphModule, recipe: list[tuple]) -> None:
        self.module, self.recipe = module, recipe
        self.forward = module.forward

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward(x)

    def rebind(self, stack: _Stack) -> None:
        views = stack._acting_views()
        values: dict[str, torch.Tensor] = {}
        for target, op, function, args, kwargs in self.recipe:
            if op == "view":
                values[target] = views[function]
                continue
            made = fx.node.map_aggregate((args, kwargs), lambda a: values[a.target] if isinstance(a, _Ref) else a)
            values[target] = _apply(op, function, *made)
        self.module.__dict__.update(values)


class _Ref:
    """An argument of a recipe's operation: the attribute made before it."""

    def __init__(self, target: str) -> None:
        self.target = target


def trace(network: nn.Module, stack: _Stack, example: torch.Tensor) -> Traced | None:
    """``network``'s acting forward on a batch of ``example``'s shape (members, batch, *observation) as one traced
    function, or ``None`` where fx cannot trace it. Every operation on weights alone that gives a view of ``flat``
    (a transpose, an unsqueeze) is done here, once."""
    views = stack._acting_views()
    tracer = _Tracer()
    stack.tracer = tracer
    root = _Acting(network)
    try:
        graph = tracer.trace(root)
    except Exception:  # control flow on values, a call fx cannot follow: the module runs as it is
        return None
    finally:
        stack.tracer = None
    constants: dict[fx.Node, torch.Tensor] = {}
    attributes: dict[str, torch.Tensor] = {}
    recipe: list[tuple] = []
    """(attribute, how: "view" of a layout name or an fx op, function, args, kwargs), in the order they are made."""
    storage = stack.flat.untyped_storage().data_ptr()
    for node in list(graph.nodes):
        if node.op == "get_attr" and node.target.startswith("_stacked_"):
            name = next(n for n in stack.layout if attribute(n) == node.target)
            constants[node] = attributes[node.target] = views[name]
            recipe.append((node.target, "view", name, (), {}))
            continue
        if node.op == "get_attr":  # a module's own constant (a buffer): read once, a plain attribute
            value = operator.attrgetter(node.target)(root)
            node.target = f"_constant_{len(attributes)}"
            attributes[node.target] = value
            continue
        if node.op not in ("call_method", "call_function") or not node.all_input_nodes:
            continue
        if not all(n in constants for n in node.all_input_nodes):
            continue
        args, kwargs = fx.node.map_arg((node.args, node.kwargs), lambda n: constants[n])
        value = _apply(node.op, node.target, args, kwargs)
        if not isinstance(value, torch.Tensor) or value.untyped_storage().data_ptr() != storage:
            continue  # a copy (a reshape that cannot view): computed at every call, as it would go stale
        target = f"_stacked_folded_{len(attributes)}"
        attributes[target] = constants[node] = value
        refs = fx.node.map_arg((node.args, node.kwargs), lambda n: _Ref(n.target))
        recipe.append((target, node.op, node.target, *refs))
        with graph.inserting_before(node):
            folded = graph.get_attr(target)
        constants[folded] = value
        node.replace_all_uses_with(folded)
        graph.erase_node(node)
    graph.eliminate_dead_code()
    copied = fx.Graph()
    copied.output(copied.graph_copy(graph, {}))
    try:
        module = fx.GraphModule(attributes, copied)
        _specialise(module, example)
    except Exception:  # shapes fx cannot propagate: the graph as traced
        module = fx.GraphModule(attributes, graph)
    for target in list(module._buffers):  # plain attributes: read without nn.Module's lookup
        module.__dict__[target] = module._buffers.pop(target)
    return Traced(module, recipe)


def _apply(op: str, function: object, args: tuple, kwargs: dict) -> object:
    return getattr(args[0], function)(*args[1:], **kwargs) if op == "call_method" else function(*args, **kwargs)


_SHAPE_ARITHMETIC = (operator.getitem, operator.add, operator.mul, operator.floordiv, operator.sub)
_ELEMENTWISE = {F.relu, torch.relu, torch.tanh, torch.sigmoid, F.gelu, F.elu, F.silu, F.leaky_relu, F.tanh, F.sigmoid}
_ELEMENTWISE_METHODS = ("relu", "tanh", "sigmoid", "exp", "neg", "abs")
_RESHAPES = ("reshape", "view", "flatten", "unflatten")


class _Meta(NamedTuple):
    shape: torch.Size
    dtype: torch.dtype
    stride: tuple[int, ...]


class _Shapes(fx.Interpreter):
    """Runs the graph once, noting each tensor's shape, dtype and strides (``node.meta["tensor"]``)."""

    def run_node(self, n: fx.Node) -> object:
        result = super().run_node(n)
        if isinstance(result, torch.Tensor):
            n.meta["tensor"] = _Meta(result.shape, result.dtype, result.stride())
        return result


def _specialise(module: fx.GraphModule, example: torch.Tensor) -> None:
    """``module``'s graph for inputs of ``example``'s shape: shape arithmetic (``x.shape``, ``x.size()``, their
    items and sums) becomes constants; a reshape to its input's shape, or one undone after an elementwise
    activation, goes; ``F.relu`` calls ``torch.relu`` (no Python wrapper)."""
    graph = module.graph
    _Shapes(module).run(example)

    def shape(node: object) -> torch.Size | None:
        meta = node.meta.get("tensor") if isinstance(node, fx.Node) else None
        return getattr(meta, "shape", None)

    constants: dict[fx.Node, object] = {}
    for node in graph.nodes:
        if node.op == "call_function" and node.target is getattr and node.args[1] == "shape" and shape(node.args[0]):
            constants[node] = shape(node.args[0])
        elif node.op == "call_method" and node.target in ("size", "dim") and shape(node.args[0]) is not None:
            on = torch.empty(shape(node.args[0]), device="meta")
            constants[node] = getattr(on, node.target)(*node.args[1:], **node.kwargs)
        elif (
            node.op == "call_function"
            and node.target in _SHAPE_ARITHMETIC
            and node.all_input_nodes
            and all(n in constants for n in node.all_input_nodes)
        ):
            args, kwargs = fx.node.map_arg((node.args, node.kwargs), lambda n: constants[n])
            constants[node] = node.target(*args, **kwargs)
    for node in graph.nodes:  # every use of a shape node: its value
        node.args, node.kwargs = fx.node.map_arg((node.args, node.kwargs), lambda n: constants.get(n, n))
    graph.eliminate_dead_code()

    def is_reshape(node: object) -> bool:
        return isinstance(node, fx.Node) and node.op == "call_method" and node.target in _RESHAPES

    def rowwise(node: object) -> bool:
        return (
            isinstance(node, fx.Node)
            and node.op == "call_function"
            and node.target in (F.layer_norm, torch.layer_norm)
            and len(node.args) > 1
            and len(node.args[1]) == 1
        )

    def elementwise(node: object) -> bool:
        return isinstance(node, fx.Node) and (
            (node.op == "call_function" and node.target in _ELEMENTWISE)
            or (node.op == "call_method" and node.target in _ELEMENTWISE_METHODS)
        )

    for node in list(graph.nodes):
        if node.op == "call_function" and node.target is F.relu and not node.kwargs.get("inplace", False):
            node.target, node.kwargs = torch.relu, {}  # F's Python wrappers: torch's own functions
        if node.op == "call_function" and node.target is F.layer_norm:
            node.target = torch.layer_norm
        if node.op == "call_method" and node.target in ("float", "contiguous") and len(node.args) == 1:
            source = node.args[0]  # a float32 input made float32, a contiguous one contiguous: the input itself
            meta, before = node.meta.get("tensor"), getattr(source, "meta", {}).get("tensor")
            if meta is not None and before is not None and meta == before:
                node.replace_all_uses_with(source)
                graph.erase_node(node)
            continue
        if not is_reshape(node) or shape(node) is None:
            continue
        source = node.args[0]
        if is_reshape(source) and len(source.users) == 1:  # reshape(reshape(a)): a reshape of a
            if shape(source.args[0]) == shape(node):
                node.replace_all_uses_with(source.args[0])
                graph.erase_node(node)
                continue
            if node.target == "reshape":
                node.args = (source.args[0], *node.args[1:])
                source = source.args[0]
        elif (  # reshape(f(reshape(a))) back to a's shape: f(a), for an elementwise f (or one over the last axis
            # that both reshapes keep)
            (
                elementwise(source)
                or (rowwise(source) and shape(source.args[0]) and shape(node)[-1:] == shape(source.args[0])[-1:])
            )
            and len(source.users) == 1
            and is_reshape(source.args[0])
            and len(source.args[0].users) == 1
            and shape(source.args[0].args[0]) == shape(node)
        ):
            source.args = (source.args[0].args[0], *source.args[1:])
            source.meta["tensor"] = node.meta["tensor"]
        if shape(source) == shape(node):  # a reshape to the shape it has
            node.replace_all_uses_with(source)
            graph.erase_node(node)
    graph.eliminate_dead_code()
    module.recompile()

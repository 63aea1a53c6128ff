"""Loading spec YAML with a bound on alias expansion.

YAML aliases (``*name``) repeat a whole anchored subtree, so a few hundred bytes can stand for
billions of nodes ("billion laughs"). PyYAML shares the aliased objects, but everything that walks
the loaded data (the schema, its checks, every dump) meets each copy. :func:`load_yaml` counts the
expanded size on the composed node graph, once per node, before building anything.
"""

from __future__ import annotations

from typing import Any

__all__ = ["MAX_YAML_NODES", "load_yaml"]


#: Most nodes (mappings, sequences and scalars) a YAML document may hold once its aliases are
#: expanded: ``*name`` repeats a whole anchored subtree, so nine nested levels of nine aliases each
#: (a "billion laughs") stand for 9^9 nodes in a few hundred bytes. A spec needs far fewer: a
#: 20x20 state-space plant is ~450 nodes, a sequence profile of 80,000 points ~240,000.
MAX_YAML_NODES = 250_000


def load_yaml(text: str) -> Any:
    """``yaml.safe_load`` that refuses a document expanding to more than MAX_YAML_NODES nodes.

    The node graph is composed first (aliases are references there, not copies), its expanded size
    counted once per node, and only then is it built into Python objects.

    Raises
    ------
    ValueError
        With the parser's message for invalid YAML; naming the limit for a document that expands
        beyond it; for an alias inside its own anchor (a recursive structure).
    """
    import yaml  # deferred on purpose: JSON specs and gains (the API, tools, start-up) never need it

    loader = yaml.SafeLoader(text)
    try:
        try:
            root = loader.get_single_node()
        except yaml.YAMLError as exc:
            raise ValueError(str(exc)) from None
        if root is None:
            return None
        _check_expanded_size(root)
        try:
            return loader.construct_document(root)
        except yaml.YAMLError as exc:
            raise ValueError(str(exc)) from None
    finally:
        loader.dispose()


def _check_expanded_size(root: Any) -> None:
    """ValueError when the YAML node graph under ``root``, aliases expanded, has more than
    MAX_YAML_NODES nodes, or an alias inside its own anchor (a cycle). Linear in the composed graph."""
    import yaml

    def children(node: Any) -> list[Any]:
        if isinstance(node, yaml.SequenceNode):
            return node.value
        if isinstance(node, yaml.MappingNode):
            return [n for pair in node.value for n in pair]
        return []

    size: dict[int, int] = {}  # expanded size per node, capped at MAX_YAML_NODES + 1
    open_: set[int] = set()  # entered, not finished: the ancestors of the node being entered
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        if finished:
            open_.discard(id(node))
            size[id(node)] = min(1 + sum(size[id(c)] for c in children(node)), MAX_YAML_NODES + 1)
            continue
        if id(node) in size:
            continue
        if id(node) in open_:
            raise ValueError(f"an alias refers to its own anchor (line {node.start_mark.line + 1}): a recursive "
                             "structure, which a spec never needs")
        open_.add(id(node))
        stack.append((node, True))
        stack.extend((c, False) for c in children(node) if id(c) not in size)
    if size[id(root)] > MAX_YAML_NODES:
        raise ValueError(f"the document expands to more than {MAX_YAML_NODES:,} nodes once its aliases (*name) "
                         f"are expanded, over the limit of {MAX_YAML_NODES:,}; write the repeated parts out or "
                         "use fewer nested aliases")

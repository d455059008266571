"""YAML text -> (plain data, node tree), so every later error can name its line.

PyYAML's ``safe_load`` throws the positions away. Composing the node graph first keeps each
node's start mark; the same graph is then constructed into plain Python data for pydantic, and a
pydantic ``loc`` tuple (``("channels", 2, "channel")``) is walked back down the graph to find the
line it came from. Duplicate mapping keys, which PyYAML would silently resolve to the last one,
are reported here because they are exactly the silent typo the config must refuse.

Every YAML input is hostile until parsed: PyYAML composes recursively and expands aliases
without limit, so a 1,000-bracket line ended in a RecursionError traceback, ``a: &x [*x]`` in a
loop, and a 9-level alias bomb (each level an alias list of the one before) made the old
duplicate-key walk visit 10**9 nodes. :class:`_BoundedLoader` refuses, with the line, nesting
deeper than :data:`MAX_DEPTH`, an alias inside the node it names, and a document whose values
(aliases counted as often as they are used) exceed :data:`MAX_VALUES`, all while composing,
before anything is expanded; and the text itself is capped at :data:`MAX_BYTES`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml
from yaml.composer import ComposerError
from yaml.constructor import ConstructorError
from yaml.events import AliasEvent
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from mavservo.errors import MavservoError

#: Deepest nesting of mappings and lists accepted, aliases expanded (the real configs use 5).
MAX_DEPTH = 32
#: Most values (scalars, lists, mappings; each use of an alias counts its whole subtree) in a
#: document: the shipped sim.yaml has ~400, so this leaves room and bounds the work per file.
MAX_VALUES = 20_000
#: Largest config text accepted: the shipped ones are 3-11 KB; PyYAML parses ~1 MB/s.
MAX_BYTES = 256 * 1024


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a config: where (key path, 1-based line) and what."""

    path: tuple[str | int, ...]
    line: int | None
    message: str

    def format(self, filename: str) -> str:
        where = f"{filename}:{self.line}" if self.line is not None else filename
        key = format_path(self.path)
        return f"{where}: {key}: {self.message}" if key else f"{where}: {self.message}"


def format_path(path: Sequence[str | int]) -> str:
    """``("channels", 2, "servo")`` -> ``channels[2].servo``."""
    text = ""
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


class YamlSyntaxError(MavservoError):
    """The text is not valid YAML; carries the 1-based line of the problem."""

    def __init__(self, line: int | None, message: str) -> None:
        super().__init__(message)
        self.line = line
        self.message = message


@dataclass(frozen=True)
class YamlDocument:
    """A parsed document: the constructed data, its node tree, and structural problems."""

    data: Any
    root: Node | None
    problems: list[Problem]

    def line_of(self, loc: Sequence[str | int]) -> tuple[tuple[str | int, ...], int | None]:
        """The key path that exists in the document for ``loc``, and the line it starts on.

        Elements of ``loc`` that do not name a node (pydantic adds union tags such as
        ``"servo_output"`` or ``"int"``) are skipped. A key that is missing from its mapping
        resolves to the mapping itself, which is the right line for "field required".
        """
        node = self.root
        path: list[str | int] = []
        line = _line(node)
        for part in loc:
            child, key_node = _child(node, part)
            if child is None:
                continue
            node = child
            path.append(part)
            # For a key, point at the key itself: an unknown key's value may be a block below it.
            line = _line(key_node) if key_node is not None else _line(child)
        return tuple(path), line

    def scalar_at(self, loc: Sequence[str | int]) -> ScalarNode | None:
        """The scalar node ``loc`` names exactly (None when it is absent or not a scalar).

        Error messages quote it as written: ``yes``, where the constructed data holds ``True``.
        """
        node = self.root
        for part in loc:
            child, _ = _child(node, part)
            if child is None:
                continue  # pydantic's union tags name no node (see line_of)
            node = child
        if node is self.root or not isinstance(node, ScalarNode):
            return None
        return node


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with bounded composition (see the module docstring).

    ``compose_node`` is where PyYAML recurses and resolves aliases, so the three limits are
    checked there, each node's expanded size and depth computed once from its children's.
    """

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self._depth = 0
        self._open_anchors: list[str] = []
        self._expanded: dict[int, tuple[int, int]] = {}  # id(node) -> (values, depth)

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        if self.check_event(AliasEvent):
            event = self.peek_event()
            if event.anchor in self._open_anchors:
                raise ComposerError(
                    None,
                    None,
                    f"alias *{event.anchor} is inside the node it names (a loop)",
                    event.start_mark,
                )
            node = self._compose(parent, index, event.start_mark)
            self._check_expanded(node, event.start_mark, f"alias *{event.anchor}")
            return node
        event = self.peek_event()
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise ComposerError(
                None, None, f"nested more than {MAX_DEPTH} levels deep", event.start_mark
            )
        if event.anchor is not None:
            self._open_anchors.append(event.anchor)
        node = self._compose(parent, index, event.start_mark)
        if event.anchor is not None:
            self._open_anchors.pop()
        self._depth -= 1
        self._expanded[id(node)] = self._measure(node)
        self._check_expanded(node, event.start_mark, "this value")
        return node

    def construct_object(self, node: Node, deep: bool = False) -> Any:
        """PyYAML's, with any failure of a constructor turned into a marked YAML error at the
        value's line: ``int("9" * 4301)`` raised a bare ValueError and ``mavservo check``
        printed a traceback (red-team finding E); bad ``!!timestamp`` values did the same."""
        try:
            return super().construct_object(node, deep)
        except yaml.YAMLError:
            raise
        except (ValueError, TypeError, OverflowError, ArithmeticError) as exc:
            raise ConstructorError(
                None, None, f"cannot read this value: {_first_line(exc)}", node.start_mark
            ) from None

    def _compose(self, parent: Node | None, index: Any, mark: Any) -> Node:
        """PyYAML's ``compose_node``, which always returns a node when it does not raise
        (its stubs allow None: such a document is refused as malformed, never passed on)."""
        node = super().compose_node(parent, index)
        if node is None:
            raise ComposerError(None, None, "expected a node here", mark)
        return node

    def _measure(self, node: Node) -> tuple[int, int]:
        """(values, depth) of ``node`` with aliases expanded, from its children's (known)."""
        children: list[Node] = []
        if isinstance(node, SequenceNode):
            children = node.value
        elif isinstance(node, MappingNode):
            children = [part for pair in node.value for part in pair]
        values, depth = 1, 1
        for child in children:
            child_values, child_depth = self._expanded.get(id(child), (1, 1))
            values += child_values
            depth = max(depth, child_depth + 1)
        return values, depth

    def _check_expanded(self, node: Node, mark: Any, what: str) -> None:
        values, depth = self._expanded.get(id(node), (1, 1))
        if values > MAX_VALUES:
            raise ComposerError(
                None,
                None,
                f"{what} holds more than {MAX_VALUES} values, each use of an alias counted"
                " in full (a config has a few hundred)",
                mark,
            )
        if self._depth + depth > MAX_DEPTH:
            raise ComposerError(
                None,
                None,
                f"{what} makes the document nest more than {MAX_DEPTH} levels deep",
                mark,
            )


def parse_yaml(text: str) -> YamlDocument:
    """Parse one YAML document; raises :class:`YamlSyntaxError` with the line on bad syntax."""
    if len(text) > MAX_BYTES:
        raise YamlSyntaxError(
            1, f"the file is {len(text)} characters long; a config has at most {MAX_BYTES}"
        )
    try:
        loader = _BoundedLoader(text)
    except yaml.reader.ReaderError as exc:  # a control character: rejected before any parsing
        raise YamlSyntaxError(
            text[: exc.position].count("\n") + 1,
            f"invalid YAML: character {exc.character!r} is not allowed",
        ) from None
    try:
        root = loader.get_single_node()
        problems: list[Problem] = []
        if root is not None:
            _find_duplicate_keys(root, (), problems)
        data = loader.construct_document(root) if root is not None else None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        if exc.context_mark is not None and mark is not None and mark.index >= len(text.rstrip()):
            # Hit the end of the file: the unclosed bracket or quote is where it went wrong.
            mark = exc.context_mark
        line = mark.line + 1 if mark is not None else None
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        hint = _syntax_hint(what) or _unclosed_hint(exc, line)
        raise YamlSyntaxError(line, f"invalid YAML: {what}{hint}") from None
    except yaml.reader.ReaderError as exc:
        raise YamlSyntaxError(
            text[: exc.position].count("\n") + 1,
            f"invalid YAML: character {exc.character!r} is not allowed",
        ) from None
    except yaml.YAMLError as exc:
        raise YamlSyntaxError(None, f"invalid YAML: {exc}") from None
    finally:
        loader.dispose()
    return YamlDocument(data, root, problems)


def _first_line(exc: BaseException) -> str:
    """The first line of an exception's text, short enough for a config error."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text[:200]


#: PyYAML's wording for the usual cause, a line indented more or less than its siblings.
_INDENTATION_SYMPTOMS = (
    "expected <block end>",
    "mapping values are not allowed here",
    "could not find expected ':'",
)


#: PyYAML's wording when a tab starts a token: in practice a tab used to indent a line.
_TAB_SYMPTOM = "found character '\\t' that cannot start any token"


def _syntax_hint(what: str) -> str:
    """A plain-words hint for the errors a mis-indented line produces (PyYAML's text is terse)."""
    if _TAB_SYMPTOM in what:
        return " (tabs are not allowed for indentation in YAML; use spaces)"
    if not any(symptom in what for symptom in _INDENTATION_SYMPTOMS):
        return ""
    quoting = "; quote a value that contains ': '" if "mapping values" in what else ""
    return (
        " (check the indentation of this line and the lines above: the keys of one mapping,"
        f" and the '-' items of one list, must start in the same column{quoting})"
    )


def _unclosed_hint(exc: yaml.MarkedYAMLError, line: int | None) -> str:
    """Name the line of a ``{`` or ``[`` that runs into the next line unclosed: PyYAML reports
    the line after it (``expected ',' or '}', but got '-'``), where nothing is wrong."""
    context = exc.context or ""
    opened = exc.context_mark.line + 1 if exc.context_mark is not None else None
    if not context.startswith("while parsing a flow") or opened is None or opened == line:
        return ""
    bracket = "{" if "mapping" in context else "["
    closing = "}" if bracket == "{" else "]"
    return f" (the {bracket!r} on line {opened} is not closed: is its {closing!r} missing?)"


def _line(node: Node | None) -> int | None:
    return node.start_mark.line + 1 if node is not None else None


def _child(node: Node | None, part: str | int) -> tuple[Node | None, Node | None]:
    """(value node, key node) for ``part`` under ``node``, or (None, None)."""
    if isinstance(node, MappingNode) and isinstance(part, str):
        for key_node, value_node in node.value:
            if isinstance(key_node, ScalarNode) and key_node.value == part:
                return value_node, key_node
    if isinstance(node, SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
        return node.value[part], None
    return None, None


def _find_duplicate_keys(
    node: Node, path: tuple[str | int, ...], out: list[Problem], seen_nodes: set[int] | None = None
) -> None:
    """Report repeated keys; a node reached again through an alias is not walked again."""
    seen_nodes = set() if seen_nodes is None else seen_nodes
    if id(node) in seen_nodes:
        return
    seen_nodes.add(id(node))
    if isinstance(node, MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, ScalarNode) else None
            if key is not None:
                if key in seen:
                    out.append(
                        Problem(
                            path + (key,),
                            _line(key_node),
                            f"duplicate key (first given on line {seen[key]})",
                        )
                    )
                else:
                    seen[key] = _line(key_node) or 0
            step = (key,) if key is not None else ()
            _find_duplicate_keys(value_node, path + step, out, seen_nodes)
    elif isinstance(node, SequenceNode):
        for index, item in enumerate(node.value):
            _find_duplicate_keys(item, path + (index,), out, seen_nodes)

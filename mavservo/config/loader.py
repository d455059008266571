"""Load a config file and turn every problem into one ``FILE:LINE: key.path: message`` line.

Validation happens in three passes, each only when the previous one found nothing, because a
later pass needs the earlier guarantees: YAML syntax and duplicate keys, then the pydantic
models (types, ranges, unknown keys), then the cross-section checks and the bus-load budget.
All problems of a pass are reported together, so one run of ``mavservo check`` shows every
typo at once instead of one per attempt.
"""

from __future__ import annotations

import difflib
import types
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails
from yaml.nodes import ScalarNode

from mavservo.config.schema import Config
from mavservo.config.semantic import Finding, advisories, budget_checks, cross_checks
from mavservo.config.smallfile import FileTooLargeError, SmallFileError, read_small_file
from mavservo.config.tunnel_plan import tunnel_checks
from mavservo.config.yamlsource import (
    MAX_BYTES,
    Problem,
    YamlDocument,
    YamlSyntaxError,
    format_path,
    parse_yaml,
)
from mavservo.errors import MavservoError

_DATA_DIR = Path(__file__).resolve().parent.parent / "data"


class ConfigError(MavservoError):
    """A config that cannot be used; ``str()`` has one ``FILE:LINE: path: message`` per problem."""

    def __init__(self, filename: str, problems: list[Problem]) -> None:
        self.filename = filename
        self.problems = sorted(problems, key=lambda p: (p.line or 0, format_path(p.path)))
        super().__init__("\n".join(p.format(filename) for p in self.problems))


def default_config_path() -> Path:
    """The built-in default (``config/sim.yaml``, shipped inside the package as data)."""
    return _DATA_DIR / "sim.yaml"


def load_config(path: str | Path) -> Config:
    """Read and validate a config file; raises :class:`ConfigError` (also for unreadable files)."""
    return load_config_with_warnings(path)[0]


def load_config_with_warnings(path: str | Path) -> tuple[Config, list[Problem]]:
    """:func:`load_config`, plus the settings that load but will not do what they say.

    The warnings (e.g. a ``telemetry_hz`` above what the telemetry loop polls) carry lines like
    errors do; ``mavservo check`` prints them, and a config with warnings is still valid.
    """
    config, warnings, _document = load_located(path)
    return config, warnings


def load_located(path: str | Path) -> tuple[Config, list[Problem], YamlDocument]:
    """:func:`load_config_with_warnings`, plus the parsed document: where each key is, for the
    problems found after loading (start-up checks, a bus that cannot open) to name their line."""
    path = Path(path)
    text = _read_text(path)
    config, document = _validate(text, str(path), path.resolve().parent)
    return config, located(advisories(config), document), document


def _read_text(path: Path) -> str:
    """The file's text, at most :data:`MAX_BYTES` (+1 to notice more) read; a ConfigError
    names the line of a byte that is not UTF-8 (binary junk gets a line like any error)."""
    try:
        data = read_small_file(path, MAX_BYTES)
    except FileTooLargeError:
        problem = Problem((), 1, f"the file is larger than {MAX_BYTES} bytes; is it a config?")
        raise ConfigError(str(path), [problem]) from None
    except SmallFileError as exc:
        problem = Problem((), None, str(exc))
        raise ConfigError(str(path), [problem]) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        problem = Problem((), line, f"not UTF-8 text: byte 0x{data[exc.start]:02x} is not valid")
        raise ConfigError(str(path), [problem]) from None


def load_config_text(text: str, filename: str = "<config>", base_dir: Path | None = None) -> Config:
    """Validate YAML text; ``filename`` is used in messages, ``base_dir`` for relative paths.

    ``base_dir`` defaults to the directory of ``filename`` (the current one for ``<config>``).
    """
    if base_dir is None:
        base_dir = Path(filename).resolve().parent if not filename.startswith("<") else Path.cwd()
    return _validate(text, filename, base_dir)[0]


def _validate(text: str, filename: str, base_dir: Path) -> tuple[Config, YamlDocument]:
    try:
        document = parse_yaml(text)
    except YamlSyntaxError as exc:
        raise ConfigError(filename, [Problem((), exc.line, exc.message)]) from None
    if document.problems:
        raise ConfigError(filename, document.problems)
    if document.data is None:
        raise ConfigError(
            filename, [Problem((), 1, "the file is empty; expected at least a 'servos' section")]
        )
    try:
        config = Config.model_validate(document.data, context={"base_dir": base_dir})
    except ValidationError as exc:
        raise ConfigError(filename, _pydantic_problems(exc, document)) from None
    for check in (cross_checks, budget_checks, tunnel_checks):
        findings = check(config)
        if findings:
            raise ConfigError(filename, located(findings, document))
    return config, document


def located(findings: list[Finding], document: YamlDocument | None) -> list[Problem]:
    """Each ``(key path, message)`` finding as a :class:`Problem` on its key's line (no line
    without a document)."""
    if document is None:
        return [Problem(tuple(loc), None, message) for loc, message in findings]
    problems = []
    for loc, message in findings:
        _, line = document.line_of(loc)
        problems.append(Problem(tuple(loc), line, message))
    return problems


# ------------------------------------------------------------------ pydantic errors -> problems


def _pydantic_problems(exc: ValidationError, document: YamlDocument) -> list[Problem]:
    errors = exc.errors(include_url=False)
    typos = _unknown_keys(errors, document)
    merged: dict[tuple[tuple[str | int, ...], int | None], list[str]] = {}
    for error in _expand_option_errors(errors):
        loc = tuple(error["loc"])
        if error["type"] == "union_tag_invalid":
            loc = loc + ("source",)
        path, line = document.line_of(loc)
        if error["type"] == "missing":
            path = path + (loc[-1],)
            message, line = _describe_missing(loc, line, typos)
        else:
            message = _describe(error, loc, document.scalar_at(loc))
        messages = merged.setdefault((path, line), [])
        if message not in messages:
            messages.append(message)
    return [Problem(path, line, " or ".join(messages)) for (path, line), messages in merged.items()]


def _expand_option_errors(errors: list[Any]) -> list[Any]:
    """A servo's ``options`` and a bus's ``node`` problems (checked by the family's models, see
    :func:`mavservo.config.schema.raise_option_problems`) become one error per key, so each is
    printed on the line of its key."""
    out: list[Any] = []
    for error in errors:
        ctx = error.get("ctx") or {}
        if error["type"] != "profile_options" or "problems" not in ctx:
            out.append(error)
            continue
        for key, message in ctx["problems"]:
            loc = (*error["loc"], ctx.get("field", "options"), *key.split("."))
            out.append({"type": "value_error", "loc": loc, "msg": message, "input": None})
    return out


def _unknown_keys(
    errors: list[Any], document: YamlDocument
) -> dict[tuple[str | int, ...], list[tuple[str, int | None]]]:
    """Unknown keys by the mapping they sit in: a missing key may be one of them misspelt."""
    typos: dict[tuple[str | int, ...], list[tuple[str, int | None]]] = {}
    for error in errors:
        if error["type"] == "extra_forbidden":
            loc = tuple(error["loc"])
            typos.setdefault(loc[:-1], []).append((str(loc[-1]), document.line_of(loc)[1]))
    return typos


def _describe_missing(
    loc: tuple[str | int, ...],
    line: int | None,
    typos: dict[tuple[str | int, ...], list[tuple[str, int | None]]],
) -> tuple[str, int | None]:
    """Put "required key is missing" on the line of an unknown key that looks like its misspelling.

    Without this, a top-level ``servo:`` typo is first reported on line 1 or 2 (the mapping the
    key is missing from), far from the line that has to change.
    """
    unknown = dict(typos.get(loc[:-1], []))
    close = difflib.get_close_matches(str(loc[-1]), list(unknown), n=1)
    if not close:
        return "required key is missing", line
    typo = close[0]
    return f"required key is missing ({typo!r} here looks like a misspelling of it)", unknown[typo]


def _describe(error: ErrorDetails, loc: tuple[str | int, ...], scalar: ScalarNode | None) -> str:
    kind = error["type"]
    if kind == "extra_forbidden":
        allowed = _allowed_keys(loc[:-1])
        hint = ""
        if allowed:
            close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            hint += f"; expected one of: {', '.join(allowed)}"
        return f"unknown key {loc[-1]!r}{hint}"
    if not loc:
        return (
            "expected a mapping of sections (mavlink, can, servos, channels, ...), "
            f"found {type(error['input']).__name__}"
        )
    message = error["msg"]
    for prefix in ("Value error, ", "Assertion failed, "):
        message = message.removeprefix(prefix)
    value = error.get("input")
    if kind in _SECTION_ERRORS:
        return _describe_section(kind, loc, value, scalar)
    if isinstance(value, (dict, list)) or kind in ("value_error", "assertion_error"):
        return message
    return f"{message}, found {_found(value, scalar, kind)}"


#: A section or list given the wrong shape: pydantic's text names Python classes
#: ("a valid dictionary or instance of MavlinkConfig"), which a YAML author cannot act on.
_SECTION_ERRORS = ("model_type", "dict_type", "list_type")


def _describe_section(
    kind: str, loc: tuple[str | int, ...], value: Any, scalar: ScalarNode | None
) -> str:
    """Say what the key needs under it, in YAML terms; an empty key is the usual cause.

    A user who deletes the only line under ``mavlink:`` (its ``url``) leaves ``mavlink:`` with
    nothing under it, which YAML reads as null.
    """
    what = "items (lines starting with '- ')" if kind == "list_type" else "keys"
    key = loc[-1]
    if value is None:
        return f"{key!r} is empty (nothing under it); write its {what} under it, indented"
    return f"expected {what} under {key!r}, found {_found(value, scalar, kind)}"


#: Strict-type errors (schema.Float/Int/Bool) that a YAML boolean or a quoted value can cause.
_NUMBER_ERRORS = ("float_type", "int_type", "int_from_float", "float_parsing", "int_parsing")
_BOOL_ERRORS = ("bool_type", "bool_parsing")


def _found(value: Any, scalar: ScalarNode | None, kind: str) -> str:
    """The offending value as the user wrote it, with a hint when YAML changed its type."""
    written = scalar.value if scalar is not None else None
    if isinstance(value, bool) and kind in _NUMBER_ERRORS:
        shown = written if written is not None else str(value).lower()
        return f"{shown} (YAML reads yes/no/on/off/true/false as booleans, not numbers)"
    if isinstance(value, str) and kind in _NUMBER_ERRORS + _BOOL_ERRORS:
        if kind in _BOOL_ERRORS:
            return f"the string {_short(value)} (write true or false, without quotes)"
        if _is_number(value):
            return f"the string {_short(value)} (write the number without quotes)"
        return f"the string {_short(value)}"
    return _short(value)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _allowed_keys(loc: tuple[str | int, ...]) -> list[str]:
    """Field names of the model that ``loc`` points into, following the schema's annotations."""
    annotation: Any = Config
    for part in loc:
        annotation = _step(annotation, part)
        if annotation is None:
            return []
    model = _as_model(annotation)
    return list(model.model_fields) if model is not None else []


def _step(annotation: Any, part: str | int) -> Any:
    """The annotation one ``loc`` element further down, or None when it cannot be followed."""
    for candidate in _flatten(annotation):
        model = _as_model(candidate)
        if model is not None and isinstance(part, str):
            if part in model.model_fields:
                return model.model_fields[part].annotation
            continue
        origin = typing.get_origin(candidate)
        if origin is list and isinstance(part, int):
            return typing.get_args(candidate)[0]
        if origin is dict and isinstance(part, str):
            return typing.get_args(candidate)[1]
    # A union tag (e.g. "servo_output"): pick the member whose ``source`` literal matches.
    for candidate in _flatten(annotation):
        model = _as_model(candidate)
        source = model.model_fields.get("source") if model is not None else None
        if source is not None and part in typing.get_args(source.annotation):
            return model
    return None


def _flatten(annotation: Any) -> list[Any]:
    """Unwrap Annotated and unions into their member types."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _flatten(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [member for arg in typing.get_args(annotation) for member in _flatten(arg)]
    return [annotation]


def _as_model(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    return None

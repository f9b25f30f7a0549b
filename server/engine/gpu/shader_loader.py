"""Compose GLSL sources from the `sphrender.shaders` package data.

Modelled on moderngl-window's shader loader: every shader lives in its own ``*.glsl`` file, a
top-level shader starts with ``#version`` on line 1, and shared code is pulled in with
``#include "path.glsl"``. Composition is purely textual and needs no GL context.

Rules
-----
* ``#version`` must be the very first line of a top-level shader (leading blanks or comments are an
  error) and must not appear anywhere else; included files may not contain ``#version`` at all.
* ``#include "relative/path.glsl"`` is resolved first relative to the including file's folder,
  then relative to the shader root. Includes are recursive. An include may not leave the root
  (``../`` past the top) and may not be absolute.
* Each file is included **at most once per composed shader**: a second ``#include`` of a file that
  is already part of the shader (e.g. a diamond ``a -> b -> common``, ``a -> c -> common``) is
  replaced by a comment line, like an implicit ``#pragma once``. So include files need no guards,
  and may hold function definitions. A true cycle (a file including one of its own includers) is
  an error showing the chain; so is nesting deeper than ``max_include_depth``.
* Includes are expanded before the GLSL preprocessor runs, so an ``#include`` inside ``#if 0`` is
  still expanded; one inside a ``/* ... */`` comment or after ``//`` is ignored.
* ``defines`` may only override object-like ``#define NAME value`` lines that the composed shader
  itself declares (top-level file or any include). The value is replaced in place, so the line
  count, the line map and any trailing comment are unchanged. Every declaration of that name is
  overridden. ``bool`` becomes ``1``/``0``, ``int`` stays an integer literal, ``float`` always
  becomes a float literal (``2.0``), and ``str`` values must be a single token.
* No ``#line`` directives are emitted. Instead every composed line carries its origin in
  `ComposedShader.line_map`, and `ShaderLoader.translate_compile_error` rewrites driver info logs
  (Mesa ``0:12(5): error: ...``, NVIDIA ``0(12) : error C0000: ...``) to ``file.glsl:LINE: ...``.
* Files are read as UTF-8 (a BOM is dropped); CRLF and lone CR line ends become LF. File reads are
  cached per loader instance (shader files are immutable package data).
"""

from __future__ import annotations

import functools
import importlib.resources
import math
import posixpath
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.resources.abc import Traversable
from pathlib import Path

__all__ = [
    "ComposedShader",
    "DefineValue",
    "ShaderDefineError",
    "ShaderLoader",
    "ShaderSourceError",
    "SourceLine",
]

DefineValue = str | int | float | bool

_SHADER_PACKAGE = "sphrender.shaders"
_READ_CACHE_SIZE = 256

_VERSION_RE = re.compile(r"^\s*#\s*version\b")
_INCLUDE_RE = re.compile(r"^\s*#\s*include\b(?P<rest>.*)$")
_INCLUDE_ARG_RE = re.compile(r'^\s*"(?P<path>[^"]+)"\s*(?://.*|/\*.*\*/\s*)?$')
_DEFINE_RE = re.compile(r"^(?P<head>\s*#\s*define\s+(?P<name>[A-Za-z_]\w*))(?P<rest>.*)$")
_BAD_VALUE_PARTS = ("//", "/*", "*/", "\\", "#")
_TOKEN_RE = re.compile(r"^[!-~]+$")  # printable ASCII, no whitespace

# Driver info-log formats: the source-string index and the line number, then the rest.
_LOG_PATTERNS: tuple[re.Pattern[str], ...] = (
    # Mesa: "0:12(5): error: `foo' undeclared"
    re.compile(r"^(?P<src>\d+):(?P<line>\d+)\(\d+\): (?P<rest>.*)$", re.DOTALL),
    # NVIDIA: "0(12) : error C0000: syntax error"
    re.compile(r"^(?P<src>\d+)\((?P<line>\d+)\) : (?P<rest>.*)$", re.DOTALL),
    # AMD / Intel on Windows, glslang: "ERROR: 0:12: 'foo' : undeclared identifier"
    re.compile(r"^(?P<kind>ERROR|WARNING): (?P<src>\d+):(?P<line>\d+): (?P<rest>.*)$", re.DOTALL),
)


@dataclass(frozen=True)
class SourceLine:
    """Where one line of a composed source came from."""

    file: str  # path relative to the shader root, e.g. "smooth/smooth_depth.frag.glsl"
    line: int  # 1-based line number in that file

    def __str__(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass(frozen=True)
class ComposedShader:
    """Final GLSL text plus the origin of each of its lines."""

    source: str  # final GLSL text to hand to the compiler
    line_map: tuple[SourceLine, ...]  # one entry per '\n'-terminated line of `source`
    name: str = ""  # the top-level shader file, relative to the root

    def __post_init__(self) -> None:
        if self.source.count("\n") != len(self.line_map):
            raise ValueError(
                f"line_map has {len(self.line_map)} entries for "
                f"{self.source.count(chr(10))} source lines"
            )

    def locate(self, composed_line: int) -> SourceLine:
        """The origin of 1-based line `composed_line` of `source`."""
        if not 1 <= composed_line <= len(self.line_map):
            raise IndexError(
                f"line {composed_line} is outside the composed shader (1..{len(self.line_map)})"
            )
        return self.line_map[composed_line - 1]


class ShaderSourceError(Exception):
    """A problem in the shader sources (or the request); the message names file and line."""

    def __init__(self, message: str, file: str | None = None, line: int | None = None) -> None:
        where = ""
        if file is not None:
            where = f"{file}:{line}: " if line is not None else f"{file}: "
        super().__init__(f"{where}{message}")
        self.file = file
        self.line = line
        self.message = message


class ShaderDefineError(ShaderSourceError, ValueError):
    """A bad `defines` override: undeclared name or a value that is not a single GLSL token."""


@dataclass(frozen=True)
class _Line:
    text: str
    origin: SourceLine
    in_comment: bool  # the line starts inside a /* ... */ block comment


class _Composer:
    """State of one `ShaderLoader.compose` call."""

    def __init__(self, loader: ShaderLoader, name: str) -> None:
        self.loader = loader
        self.name = name
        self.out: list[_Line] = []
        self.included: set[str] = set()

    def run(self) -> list[_Line]:
        lines = self.loader._read_lines(self.name, None)
        if not lines or not _VERSION_RE.match(lines[0]):
            raise ShaderSourceError(
                "a top-level shader must start with '#version' on its first line", self.name, 1
            )
        self._expand(self.name, (self.name,), top_level=True)
        return self.out

    def _expand(self, rel: str, chain: tuple[str, ...], *, top_level: bool) -> None:
        self.included.add(rel)
        lines = self.loader._read_lines(rel, None)
        in_comment = False
        for number, text in enumerate(lines, start=1):
            origin = SourceLine(rel, number)
            starts_in_comment = in_comment
            in_comment = _block_comment_state(text, in_comment)
            if starts_in_comment:
                self.out.append(_Line(text, origin, True))
                continue
            if _VERSION_RE.match(text) and not (top_level and number == 1):
                why = (
                    "'#version' is only allowed on the first line"
                    if top_level
                    else "an included file must not contain '#version'"
                )
                raise ShaderSourceError(why, rel, number)
            include = _INCLUDE_RE.match(text)
            if include is None:
                self.out.append(_Line(text, origin, False))
                continue
            target = self._resolve_include(rel, number, include.group("rest"))
            if target in chain:
                shown = " -> ".join((*chain, target))
                raise ShaderSourceError(f"include cycle: {shown}", rel, number)
            if target in self.included:
                # Already part of this shader: skip it (implicit #pragma once), keep the line.
                # The note must not read as a directive: moderngl resolves any '#include "..."'
                # left in a source it compiles, comments included, and fails on it.
                note = f'// "{target}" skipped: included above'
                self.out.append(_Line(note, origin, False))
                continue
            if len(chain) > self.loader.max_include_depth:
                shown = " -> ".join((*chain, target))
                raise ShaderSourceError(
                    f"includes nested deeper than {self.loader.max_include_depth}: {shown}",
                    rel,
                    number,
                )
            self._expand(target, (*chain, target), top_level=False)

    def _resolve_include(self, rel: str, number: int, rest: str) -> str:
        arg = _INCLUDE_ARG_RE.match(rest)
        if arg is None:
            raise ShaderSourceError(
                f'malformed include {rest.strip()!r}; expected #include "path.glsl"', rel, number
            )
        path = arg.group("path")
        if path.startswith("/"):
            raise ShaderSourceError(f"include path {path!r} must be relative", rel, number)
        folder_relative = _normalise(posixpath.join(posixpath.dirname(rel), path))
        if _escapes(folder_relative):
            # If it escapes from the including folder, it escapes from the root as well.
            raise ShaderSourceError(
                f"include {path!r} resolves outside the shader root", rel, number
            )
        candidates = [folder_relative]
        root_relative = _normalise(path)
        if root_relative not in candidates and not _escapes(root_relative):
            candidates.append(root_relative)
        for candidate in candidates:
            if self.loader._is_file(candidate):
                return candidate
        tried = ", ".join(repr(c) for c in candidates)
        raise ShaderSourceError(f"included file {path!r} not found (tried {tried})", rel, number)


class ShaderLoader:
    """Loads and composes GLSL shaders below `root` (default: the `sphrender.shaders` package)."""

    def __init__(
        self,
        root: Traversable | Path | None = None,
        *,
        max_include_depth: int = 8,
    ) -> None:
        if isinstance(max_include_depth, bool) or not isinstance(max_include_depth, int):
            raise TypeError("max_include_depth must be an int")
        if max_include_depth < 0:
            raise ValueError("max_include_depth must be >= 0")
        self._root: Traversable | Path = (
            importlib.resources.files(_SHADER_PACKAGE) if root is None else root
        )
        self.max_include_depth = max_include_depth
        # Per-instance cache of decoded, line-split files, keyed by root-relative path.
        self._cached_read: Callable[[str], tuple[str, ...] | None] = functools.lru_cache(
            maxsize=_READ_CACHE_SIZE
        )(self._read_uncached)

    @property
    def root(self) -> Traversable | Path:
        """The folder shader names are relative to."""
        return self._root

    # -- composition -------------------------------------------------------------------------

    def compose(
        self, name: str, defines: Mapping[str, DefineValue] | None = None
    ) -> ComposedShader:
        """Compose top-level shader `name` (root-relative), with `#include`s spliced in and
        declared `#define`s overridden by `defines`."""
        rel = _normalise(name)
        if name.startswith("/") or _escapes(rel):
            raise ShaderSourceError(f"shader name {name!r} must be a path inside the shader root")
        if not self._is_file(rel):
            raise ShaderSourceError(f"shader {name!r} not found in {self._root}")
        lines = _Composer(self, rel).run()
        texts = [line.text for line in lines]
        if defines:
            self._apply_defines(rel, lines, texts, defines)
        source = "".join(f"{text}\n" for text in texts)
        return ComposedShader(source, tuple(line.origin for line in lines), rel)

    def _apply_defines(
        self,
        name: str,
        lines: list[_Line],
        texts: list[str],
        defines: Mapping[str, DefineValue],
    ) -> None:
        declared: dict[str, list[int]] = {}
        for index, line in enumerate(lines):
            if line.in_comment:
                continue
            match = _DEFINE_RE.match(line.text)
            if match is None or match.group("rest").startswith("("):
                continue  # not a define, or a function-like macro
            declared.setdefault(match.group("name"), []).append(index)
        undeclared = sorted(key for key in defines if key not in declared)
        if undeclared:
            names = ", ".join(repr(key) for key in undeclared)
            verb = "is" if len(undeclared) == 1 else "are"
            listed = ", ".join(sorted(declared)) or "(none)"
            raise ShaderDefineError(f"{names} {verb} not declared by {name}; declared: {listed}")
        for key, value in defines.items():
            token = format_define_value(key, value)
            for index in declared[key]:
                line = lines[index]
                if texts[index].rstrip().endswith("\\"):
                    raise ShaderDefineError(
                        f"cannot override multi-line #define {key!r}",
                        line.origin.file,
                        line.origin.line,
                    )
                texts[index] = _replace_define_value(texts[index], token)

    # -- error logs --------------------------------------------------------------------------

    def translate_compile_error(self, shader: ComposedShader, log: str) -> str:
        """Rewrite a driver info log so line numbers refer to the original files.

        Lines like ``0:12(5): error: ...`` (Mesa) or ``0(12) : error C0000: ...`` (NVIDIA) become
        ``file.glsl:LINE: error: ...``. Anything else (other formats, other source strings, line
        numbers outside the shader) passes through unchanged.
        """
        out: list[str] = []
        for raw in log.splitlines(keepends=True):
            body = raw.rstrip("\r\n")
            ending = raw[len(body) :]
            out.append(_translate_log_line(shader, body) + ending)
        return "".join(out)

    # -- file access -------------------------------------------------------------------------

    def _node(self, rel: str) -> Traversable | Path:
        node: Traversable | Path = self._root
        for part in rel.split("/"):
            node = node.joinpath(part)
        return node

    def _is_file(self, rel: str) -> bool:
        return self._cached_read(rel) is not None

    def _read_lines(self, rel: str, line: int | None) -> tuple[str, ...]:
        lines = self._cached_read(rel)
        if lines is None:
            raise ShaderSourceError("file not found", rel, line)
        return lines

    def _read_uncached(self, rel: str) -> tuple[str, ...] | None:
        node = self._node(rel)
        try:
            if not node.is_file():
                return None
            data = node.read_bytes()
        except OSError:
            return None
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise ShaderSourceError(f"not valid UTF-8: {exc}", rel) from None
        text = text.replace("\r\n", "\n").replace("\r", "\n")
        lines = text.split("\n")
        if lines and lines[-1] == "":
            lines.pop()
        return tuple(lines)


def format_define_value(name: str, value: DefineValue) -> str:
    """The GLSL token for a `defines` value: bool -> 1/0, int as is, float always a float literal,
    str validated as a single token."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ShaderDefineError(f"define {name!r}: {value!r} is not a finite float")
        return repr(value)  # always has '.' or an exponent: "2.0", "1e-05", "1.5e+20"
    if isinstance(value, str):
        if not _TOKEN_RE.match(value) or any(part in value for part in _BAD_VALUE_PARTS):
            raise ShaderDefineError(
                f"define {name!r}: {value!r} is not a single token "
                "(no whitespace, newlines, comments, '#' or '\\')"
            )
        return value
    raise ShaderDefineError(
        f"define {name!r}: unsupported value type {type(value).__name__} "
        "(use str, int, float or bool)"
    )


def _replace_define_value(text: str, token: str) -> str:
    match = _DEFINE_RE.match(text)
    assert match is not None
    rest = match.group("rest")
    body = rest.lstrip()
    lead = rest[: len(rest) - len(body)] or " "
    cuts = [i for i in (body.find("//"), body.find("/*")) if i >= 0]
    value_end = min(cuts) if cuts else len(body)
    value = body[:value_end].rstrip()
    tail = body[len(value) :]
    if not tail.strip():
        tail = ""
    elif not tail[0].isspace():
        tail = " " + tail
    return f"{match.group('head')}{lead}{token}{tail}"


def _translate_log_line(shader: ComposedShader, text: str) -> str:
    for pattern in _LOG_PATTERNS:
        match = pattern.match(text)
        if match is None:
            continue
        if int(match.group("src")) != 0:
            return text
        number = int(match.group("line"))
        if not 1 <= number <= len(shader.line_map):
            return text
        origin = shader.line_map[number - 1]
        groups = match.groupdict()
        kind = f"{groups['kind']}: " if groups.get("kind") else ""
        return f"{origin.file}:{origin.line}: {kind}{match.group('rest')}"
    return text


def _normalise(path: str) -> str:
    return posixpath.normpath(path) if path else path


def _escapes(rel: str) -> bool:
    return rel in ("", ".", "..") or rel.startswith(("../", "/"))


def _block_comment_state(text: str, in_comment: bool) -> bool:
    """Whether a /* ... */ comment is still open at the end of `text`."""
    i = 0
    n = len(text)
    while i < n:
        if in_comment:
            end = text.find("*/", i)
            if end < 0:
                return True
            in_comment = False
            i = end + 2
        else:
            line_comment = text.find("//", i)
            block = text.find("/*", i)
            if block < 0 or (0 <= line_comment < block):
                return False
            in_comment = True
            i = block + 2
    return in_comment

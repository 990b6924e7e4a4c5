"""What each module of a Rust crate's library uses, read from its source: the input of
scripts/module_cycles.py.

A module's uses are the paths it names that lead into the crate: its ``use`` declarations and
the ``crate::`` / ``super::`` / ``self::`` paths in its code. Each is resolved to the module
that defines the named item, following the re-exports on the way (``pub use``, private
imports that child modules reach through ``super::``, and glob imports). Modules under
``#[cfg(test)]`` are left out, as they are from the library.

What it does not see, against a full name resolver (rust-analyzer, which cargo-modules runs):
a bare name used through a glob import of a sibling (``use crate::a::*;`` is one edge to ``a``
whatever it brings in), macro-generated paths, and ``#[path]`` attributes. Each of these is
absent from this workspace; ``module_cycles.py`` rejects ``#[path]`` rather than misread it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"

# Comments, strings (raw, byte, plain) and char literals, blanked before anything is read.
_LEXEMES = re.compile(
    r"""//[^\n]*
    | /\*
    | b?r(?P<hashes>\#*)"(?:.|\n)*?"(?P=hashes)
    | b?"(?:\\.|[^"\\])*"
    | b?'(?:\\(?:x[0-9a-fA-F]{2}|u\{[0-9a-fA-F]+\}|.)|[^'\\\n])'
    """,
    re.VERBOSE | re.DOTALL,
)
_MOD = re.compile(rf"\b(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+({IDENT})\s*([;{{])")
_CFG_TEST = re.compile(r"#\[cfg\(test\)\]\s*(?:#\[[^\]]*\]\s*)*$")
_USE = re.compile(r"\buse\s+([^;]+);")
_PATH = re.compile(rf"(?<![\w:$])(\$crate|crate|super|self)((?:\s*::\s*{IDENT})+)")
_ITEM = re.compile(
    rf"\b(?:fn|struct|enum|trait|type|const|static|union)\s+({IDENT})|macro_rules!\s*({IDENT})"
)


class SourceError(ValueError):
    """A crate's source that this reader cannot follow faithfully."""


def blank(text: str) -> str:
    """``text`` with comments, strings and char literals replaced by spaces (newlines kept)."""
    out, pos = [], 0
    while m := _LEXEMES.search(text, pos):
        out.append(text[pos : m.start()])
        end = _block_comment_end(text, m.start()) if m[0] == "/*" else m.end()
        out.append(re.sub(r"[^\n]", " ", text[m.start() : end]))
        pos = end
    out.append(text[pos:])
    return "".join(out)


def _block_comment_end(text: str, start: int) -> int:
    depth, i = 0, start
    while i < len(text):
        if text.startswith("/*", i):
            depth, i = depth + 1, i + 2
        elif text.startswith("*/", i):
            depth, i = depth - 1, i + 2
            if depth == 0:
                return i
        else:
            i += 1
    raise SourceError("an unterminated block comment")


def _matching_brace(text: str, open_at: int) -> int:
    depth = 0
    for i in range(open_at, len(text)):
        if text[i] == "{":
            depth += 1
        elif text[i] == "}":
            depth -= 1
            if depth == 0:
                return i
    raise SourceError("an unbalanced brace")


@dataclass
class Module:
    """One module: its own code (child modules' bodies cut out), children and imports."""

    path: str
    code: str = ""
    children: set[str] = field(default_factory=set)
    defined: set[str] = field(default_factory=set)
    uses: list[list[str]] = field(default_factory=list)  # every `use` path, as written
    imports: dict[str, list[str]] = field(default_factory=dict)  # name -> path as written
    globs: list[list[str]] = field(default_factory=list)


def use_tree(tree: str) -> list[list[str]]:
    """The paths of one ``use`` declaration's tree (``a::{b, c::d as e, f::*}``), each a list
    of segments ending in the imported name, ``*``, or ``as``-renamed as ``[..., name, '=',
    alias]``."""
    tree = re.sub(r"\s+", " ", tree).strip()
    paths: list[list[str]] = []

    def walk(s: str, prefix: list[str]) -> None:
        s = s.strip()
        if not s:
            return
        brace = s.find("{")
        if brace >= 0:
            head = [p.strip() for p in s[:brace].split("::") if p.strip()]
            inner = s[brace + 1 : s.rfind("}")]
            for part in _split_top(inner):
                walk(part, prefix + head)
            return
        alias = None
        if " as " in s:
            s, alias = (x.strip() for x in s.split(" as ", 1))
        segs = prefix + [p.strip() for p in s.lstrip(":").split("::") if p.strip()]
        if segs and segs[-1] == "self":  # `a::{self}` imports `a`
            segs = segs[:-1]
        if segs:
            paths.append(segs + (["=", alias] if alias else []))

    walk(tree.removeprefix("::"), [])
    return paths


def _split_top(s: str) -> list[str]:
    parts, depth, cur = [], 0, []
    for ch in s:
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur))
    return parts


def crate_name(crate_dir: Path) -> str:
    """The library's name as paths spell it (``sim-core`` -> ``sim_core``)."""
    sections: dict[str, dict[str, str]] = {}
    section = ""
    for line in (crate_dir / "Cargo.toml").read_text().splitlines():
        if m := re.match(r"\s*\[([^\]]+)\]", line):
            section = m[1].strip()
        elif m := re.match(r'\s*name\s*=\s*"([^"]+)"', line):
            sections.setdefault(section, {})["name"] = m[1]
    name = sections.get("lib", {}).get("name") or sections["package"]["name"]
    return name.replace("-", "_")


def read_crate(crate_dir: Path) -> dict[str, Module]:
    """Every module of the library at ``crate_dir/src/lib.rs``, by path (``sim_core::world``)."""
    root = crate_name(crate_dir)
    modules: dict[str, Module] = {}
    _read_module(modules, root, crate_dir / "src" / "lib.rs", None)
    return modules


def _read_module(modules, path: str, file: Path, code: str | None, dir_: Path | None = None):
    """Reads module ``path`` from ``file`` (or ``code``, an inline module's body); ``dir_`` is
    where its file children live."""
    if code is None:
        code = blank(file.read_text())
        if re.search(r"#\[path\b", code):
            raise SourceError(f"{file}: #[path] attributes are not followed")
        is_dir_owner = file.name in ("lib.rs", "mod.rs", "main.rs")
        dir_ = file.parent if is_dir_owner else file.parent / file.stem
    module = Module(path)
    modules[path] = module
    own, pos = [], 0
    while m := _MOD.search(code, pos):
        name, kind = m[1], m[2]
        test_only = bool(_CFG_TEST.search(code[max(0, m.start() - 200) : m.start()]))
        if kind == "{":
            close = _matching_brace(code, m.end() - 1)
            body, end = code[m.end() : close], close + 1
        else:
            body, end = None, m.end()
        own.append(code[pos : m.start()])
        pos = end
        if test_only:
            continue
        module.children.add(name)
        child = f"{path}::{name}"
        if body is not None:
            _read_module(modules, child, file, body, dir_ / name)
        else:
            candidates = [dir_ / f"{name}.rs", dir_ / name / "mod.rs"]
            found = [c for c in candidates if c.exists()]
            if not found:
                raise SourceError(f"{file}: `mod {name};` has no file ({candidates[0]})")
            _read_module(modules, child, found[0], None)
    own.append(code[pos:])
    module.code = "".join(own)
    for m in _ITEM.finditer(module.code):
        module.defined.add(m[1] or m[2])
    for m in _USE.finditer(module.code):
        for segs in use_tree(m[1]):
            target = segs[:-2] if "=" in segs else segs  # `a::b as c` names a::b
            if target[-1] == "*":
                module.globs.append(target[:-1])
                module.uses.append(target[:-1])
                continue
            module.imports[segs[-1]] = target
            module.uses.append(target)


class Resolver:
    """Resolves a path named in a module to the module that defines its item."""

    def __init__(self, modules: dict[str, Module], root: str):
        self.modules, self.root = modules, root

    def start(self, segs: list[str], here: str) -> tuple[str, list[str]] | None:
        """The module a path's first segment names, and the rest; None for an external path."""
        first, rest = segs[0], segs[1:]
        if first in ("crate", "$crate"):
            return self.root, rest
        if first == "self":
            return here, rest
        if first == "super":
            cur = here
            while True:
                cur = cur.rsplit("::", 1)[0]
                if not rest or rest[0] != "super":
                    return cur, rest
                rest = rest[1:]
        if first in self.modules[here].children:
            return f"{here}::{first}", rest
        return None

    def resolve(self, segs: list[str], here: str, depth: int = 0) -> str | None:
        """The defining module of the item ``segs`` names from module ``here`` (the last
        module on the way where the item is not found: a variant, a method); None for an
        external path."""
        started = self.start(segs, here)
        if started is None:
            return None
        found, reached = self._lookup(*started, depth)
        if found is None:
            return reached
        return found if found != _EXTERNAL else None

    def _lookup(self, cur: str, rest: list[str], depth: int) -> tuple[str | None, str]:
        """``(defining module or None, the last module reached)`` of ``rest`` inside ``cur``;
        the defining module is ``_EXTERNAL`` for an import from outside the crate."""
        while rest:
            name, module = rest[0], self.modules[cur]
            if name in module.children:
                cur, rest = f"{cur}::{name}", rest[1:]
                continue
            if name in module.defined:
                return cur, cur
            if depth > 16:
                return None, cur
            if name in module.imports:
                target = module.imports[name] + rest[1:]
                started = self.start(target, cur)
                if started is None:
                    return _EXTERNAL, cur
                return self._lookup(*started, depth + 1)
            for glob in module.globs:
                started = self.start(glob, cur)
                if started is None:
                    continue
                inner, _ = self._lookup(*started, depth + 1)
                if inner is None or inner == _EXTERNAL or inner not in self.modules:
                    continue
                found, _ = self._lookup(inner, [name, *rest[1:]], depth + 1)
                if found is not None:
                    return found, cur
            return None, cur  # not found: a name this reader cannot place
        return cur, cur


_EXTERNAL = "<external>"


def module_uses(crate_dir: Path) -> tuple[set[str], list[tuple[str, str]]]:
    """The crate's modules and its uses ``(module, defining module of what it names)``, the
    shape ``module_cycles.sibling_edges`` reads."""
    modules = read_crate(crate_dir)
    resolver = Resolver(modules, crate_name(crate_dir))
    uses: list[tuple[str, str]] = []
    for path, module in modules.items():
        named = list(module.uses)
        code = _USE.sub(" ", module.code)
        named += [[m[1], *re.split(r"\s*::\s*", m[2].strip())[1:]] for m in _PATH.finditer(code)]
        for segs in named:
            if segs and (target := resolver.resolve(segs, path)) is not None:
                uses.append((path, target))
    return set(modules), uses


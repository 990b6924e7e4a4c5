"""The two structure checks of `make test` (scripts/module_cycles.py, scripts/long_functions.py)
on small inputs: each finds what it is for, and nothing else."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))

import long_functions  # noqa: E402
import module_cycles  # noqa: E402
import rust_uses  # noqa: E402

MODULES = {"c", "c::a", "c::b", "c::d", "c::d::x", "c::d::y"}


def test_a_cycle_between_sibling_modules_is_found_with_its_uses():
    uses = [("c::a::F", "c::b::G"), ("c::b::G::m", "c::a::H"), ("c::d::x::f", "c::a::F")]
    edges = module_cycles.sibling_edges(MODULES, uses)
    assert set(edges["c"]) == {("c::a", "c::b"), ("c::b", "c::a"), ("c::d", "c::a")}
    assert module_cycles.cycles(edges["c"]) == [["c::a", "c::b"]]


def test_uses_within_a_module_and_of_ancestors_are_no_sibling_edges():
    uses = [("c::a::F::m", "c::a::F"), ("c::d::x::f", "c::d"), ("c", "c::a::F")]
    assert not module_cycles.sibling_edges(MODULES, uses)
    deeper = module_cycles.sibling_edges(MODULES, [("c::d::x::f", "c::d::y::g")])
    assert module_cycles.cycles(deeper["c::d"]) == []


def _crate(tmp_path, files: dict[str, str]):
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "Cargo.toml").write_text('[package]\nname = "tiny-crate"\n')
    for name, text in files.items():
        path = tmp_path / "src" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_a_planted_cycle_in_rust_source_fails_the_check(tmp_path, capsys):
    crate = _crate(
        tmp_path,
        {
            "lib.rs": "pub mod a;\npub mod b;\npub use a::Thing;\n",
            "a.rs": "pub struct Thing;\npub fn f() { crate::b::g() }\n",
            # through the crate root's re-export: b -> a, closing a -> b -> a
            "b.rs": "use crate::Thing;\npub fn g() { let _t = Thing; }\n",
        },
    )
    assert module_cycles.main([str(crate)]) == 1
    out = capsys.readouterr().out
    assert "cycle among the modules of tiny_crate: tiny_crate::a, tiny_crate::b" in out


def test_tests_comments_and_strings_make_no_rust_uses(tmp_path):
    crate = _crate(
        tmp_path,
        {
            "lib.rs": "mod a;\nmod b;\n",
            "a/mod.rs": "mod inner { pub fn h() { super::super::b::g(); } }\npub fn f() {}\n",
            "b.rs": (
                "// crate::a::f()\n/* use crate::a; /* nested */ */\n"
                'pub fn g() { let _s = "crate::a::f()"; }\n'
                "#[cfg(test)]\nmod tests {\n    use crate::a::f;\n}\n"
            ),
        },
    )
    modules, uses = rust_uses.module_uses(crate)
    assert modules == {"tiny_crate", "tiny_crate::a", "tiny_crate::a::inner", "tiny_crate::b"}
    assert uses == [("tiny_crate::a::inner", "tiny_crate::b")]
    assert module_cycles.main([str(crate)]) == 0


def test_long_functions_are_measured_in_both_languages(tmp_path):
    py = tmp_path / "m.py"
    py.write_text("def f():\n" + "    x = 1\n" * 5 + "\n\ndef g():\n    pass\n")
    assert dict(long_functions.python_functions(py)) == {"f": 6, "g": 2}
    rs = tmp_path / "m.rs"
    rs.write_text(
        'fn f() {\n    let s = "}";\n    if true {\n    }\n}\n'
        "fn g();\n#[cfg(test)]\nmod tests {\n    fn t() {\n    }\n}\n"
    )
    assert dict(long_functions.rust_functions(rs)) == {"f": 5, "g": 1}


@pytest.mark.parametrize(
    ("lib", "message"),
    [
        ('#[path = "other.rs"]\nmod a;\n', "#\\[path\\] attributes are not followed"),
        ("mod gone;\n", "`mod gone;` has no file"),
        ("mod a {\n    fn f() {}\n", "an unbalanced brace"),
        ("/* never closed\nmod a;\n", "an unterminated block comment"),
    ],
)
def test_rust_source_the_reader_cannot_follow_is_an_error(tmp_path, lib, message):
    with pytest.raises(rust_uses.SourceError, match=message):
        rust_uses.module_uses(_crate(tmp_path, {"lib.rs": lib}))

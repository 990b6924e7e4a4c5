"""The repository's checks on small inputs: the two structure checks of `make test`
(scripts/module_cycles.py, scripts/long_functions.py) and the wheel's glibc check of `make
wheel-check` (scripts/wheel_check.py): each finds what it is for, and nothing else."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

import long_functions  # noqa: E402
import module_cycles  # noqa: E402
import rust_uses  # noqa: E402
import wheel_check  # noqa: E402

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


def _wheel(path: Path, tag: str, files: dict[str, bytes]) -> Path:
    """A wheel named for ``tag`` holding ``files`` and the WHEEL metadata that repeats the tag."""
    import zipfile

    wheel = path / f"tiny-0.1.0-py3-none-{tag}.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for name, data in files.items():
            archive.writestr(name, data)
        tags = "".join(f"Tag: py3-none-{t}\n" for t in tag.split("."))
        archive.writestr("tiny-0.1.0.dist-info/WHEEL", f"Wheel-Version: 1.0\n{tags}")
    return wheel


# A real binary of this machine: linked against its glibc, as the wheel of a plain `cargo build`.
SYSTEM_BINARY = Path("/bin/true")


def test_the_wheel_check_refuses_a_binary_newer_than_its_promise(tmp_path, capsys):
    from elftools.elf.elffile import ELFFile

    with SYSTEM_BINARY.open("rb") as f:
        need, symbol = wheel_check.highest_glibc(ELFFile(f))
    assert need > (2, 17), "this machine's glibc is older than the check's target"
    files = {"tiny-0.1.0.data/scripts/tool": SYSTEM_BINARY.read_bytes()}
    # tagged manylinux2014 but linked against this machine's glibc: the binary breaks the promise
    wheel = _wheel(tmp_path, "manylinux2014_x86_64.manylinux_2_17_x86_64", files)
    assert wheel_check.main([str(wheel), "--max-glibc", "2.17"]) == 1
    out = capsys.readouterr().out
    assert f"tiny-0.1.0.data/scripts/tool requires {symbol} > GLIBC_2.17" in out
    assert "needs glibc" not in out  # the tags keep the promise; only the binary breaks it
    # the same binary at exactly its own glibc passes, one minor version below it fails
    honest = _wheel(tmp_path, f"manylinux_{need[0]}_{need[1]}_x86_64", files)
    assert wheel_check.main([str(honest), "--max-glibc", f"{need[0]}.{need[1]}"]) == 0
    assert wheel_check.main([str(honest), "--max-glibc", f"{need[0]}.{need[1] - 1}"]) == 1
    assert f"needs glibc {need[0]}.{need[1]} > {need[0]}.{need[1] - 1}" in capsys.readouterr().out


@pytest.mark.parametrize(
    "tag, files, message",
    [
        ("linux_x86_64", {"t/tool": SYSTEM_BINARY.read_bytes()}, "promises no glibc"),
        ("manylinux_2_17_x86_64", {"t/readme.txt": b"text"}, "holds no ELF binary"),
        ("any", {"t/tool": SYSTEM_BINARY.read_bytes()}, "no platform tag"),
        ("manylinux_2_17_x86_64", {"t/tool": b"\x7fELF broken"}, "broken ELF file"),
    ],
)
def test_a_wheel_the_check_cannot_vouch_for_fails_it(tmp_path, capsys, tag, files, message):
    wheel = _wheel(tmp_path, tag, files)
    assert wheel_check.main([str(wheel)]) == 1
    assert message in capsys.readouterr().out


def test_a_file_that_is_no_wheel_and_a_malformed_glibc_bound_are_named(tmp_path, capsys):
    not_a_zip = tmp_path / "tiny-0.1.0-py3-none-manylinux_2_17_x86_64.whl"
    not_a_zip.write_text("not a zip")
    assert wheel_check.main([str(not_a_zip)]) == 1
    assert "not a readable wheel" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        wheel_check.main([str(not_a_zip), "--max-glibc", "2.17.1"])
    assert "a glibc version is MAJOR.MINOR, like 2.17: '2.17.1'" in capsys.readouterr().err

"""Unit tests for the GLSL shader loader (no GL context needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from sphrender.server.engine.gpu.shader_loader import (
    ComposedShader,
    ShaderDefineError,
    ShaderLoader,
    ShaderSourceError,
    SourceLine,
    format_define_value,
)


def write_tree(root: Path, files: dict[str, str]) -> ShaderLoader:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text.encode("utf-8"))
    return ShaderLoader(root)


def lines_of(shader: ComposedShader) -> list[str]:
    return shader.source.split("\n")[:-1]


# -- #version ---------------------------------------------------------------------------------


def test_version_first_line_ok(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.frag.glsl": "#version 330 core\nvoid main() {}\n"})
    shader = loader.compose("a.frag.glsl")
    assert shader.source == "#version 330 core\nvoid main() {}\n"
    assert shader.line_map == (SourceLine("a.frag.glsl", 1), SourceLine("a.frag.glsl", 2))
    assert shader.name == "a.frag.glsl"


def test_version_missing(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "void main() {}\n"})
    with pytest.raises(ShaderSourceError, match=r"a\.glsl:1: .*#version"):
        loader.compose("a.glsl")


def test_empty_shader_has_no_version(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": ""})
    with pytest.raises(ShaderSourceError, match=r"a\.glsl:1: .*#version"):
        loader.compose("a.glsl")


@pytest.mark.parametrize(
    "text",
    ["\n#version 330\n", "// header\n#version 330\n", "/* c */\n#version 330\n"],
)
def test_version_not_on_first_line(tmp_path: Path, text: str) -> None:
    loader = write_tree(tmp_path, {"a.glsl": text})
    with pytest.raises(ShaderSourceError) as info:
        loader.compose("a.glsl")
    assert info.value.file == "a.glsl"
    assert info.value.line in (1, 2)


def test_duplicate_version_in_top_level(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\nfloat x;\n#version 330\n"})
    with pytest.raises(ShaderSourceError, match=r"a\.glsl:3: .*first line"):
        loader.compose("a.glsl")


def test_version_in_include_is_error(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": '#version 330\n#include "lib.glsl"\n',
            "lib.glsl": "// library\n#version 330\nfloat f();\n",
        },
    )
    with pytest.raises(ShaderSourceError, match=r"lib\.glsl:2: .*must not contain '#version'"):
        loader.compose("a.glsl")


def test_version_mentioned_in_comment_of_include_is_fine(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": '#version 330\n#include "lib.glsl"\n',
            "lib.glsl": "/* needs\n#version 330\n*/\nfloat f();\n",
        },
    )
    assert "float f();" in loader.compose("a.glsl").source


def test_crlf_and_bom_normalised(tmp_path: Path) -> None:
    (tmp_path / "a.glsl").write_bytes(b"\xef\xbb\xbf#version 330\r\nfloat x;\r\nfloat y;\rend\r\n")
    shader = ShaderLoader(tmp_path).compose("a.glsl")
    assert shader.source == "#version 330\nfloat x;\nfloat y;\nend\n"
    assert len(shader.line_map) == 4


def test_missing_trailing_newline(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\nvoid main() {}"})
    shader = loader.compose("a.glsl")
    assert shader.source == "#version 330\nvoid main() {}\n"
    assert len(shader.line_map) == 2


def test_missing_top_level_shader(tmp_path: Path) -> None:
    loader = ShaderLoader(tmp_path)
    with pytest.raises(ShaderSourceError, match="not found"):
        loader.compose("nope.glsl")
    with pytest.raises(ShaderSourceError, match="inside the shader root"):
        loader.compose("../outside.glsl")


# -- includes ---------------------------------------------------------------------------------

NESTED = {
    "main.frag.glsl": (
        "#version 330 core\n"  # 1
        "// main\n"  # 2
        '#include "lib/one.glsl"\n'  # 3
        "void main() {\n"  # 4
        "    one();\n"  # 5
        "}\n"  # 6
    ),
    "lib/one.glsl": (
        "// one, line 1\n"  # 1
        '#include "two.glsl"\n'  # 2: relative to lib/
        "float one() { return two(); }\n"  # 3
    ),
    "lib/two.glsl": (
        "// two, line 1\n"  # 1
        "// two, line 2\n"  # 2
        '#include "deep/three.glsl"\n'  # 3: relative to lib/
        "float two() { return three(); }\n"  # 4
    ),
    "lib/deep/three.glsl": (
        "float three() {\n"  # 1
        "    return 3.0;\n"  # 2
        "}\n"  # 3
    ),
}


def test_nested_includes_line_map(tmp_path: Path) -> None:
    shader = write_tree(tmp_path, NESTED).compose("main.frag.glsl")
    assert lines_of(shader) == [
        "#version 330 core",
        "// main",
        "// one, line 1",
        "// two, line 1",
        "// two, line 2",
        "float three() {",
        "    return 3.0;",
        "}",
        "float two() { return three(); }",
        "float one() { return two(); }",
        "void main() {",
        "    one();",
        "}",
    ]
    assert len(shader.line_map) == 13
    assert shader.locate(1) == SourceLine("main.frag.glsl", 1)
    assert shader.locate(2) == SourceLine("main.frag.glsl", 2)
    assert shader.locate(3) == SourceLine("lib/one.glsl", 1)
    assert shader.locate(4) == SourceLine("lib/two.glsl", 1)
    assert shader.locate(5) == SourceLine("lib/two.glsl", 2)
    assert shader.locate(6) == SourceLine("lib/deep/three.glsl", 1)
    assert shader.locate(7) == SourceLine("lib/deep/three.glsl", 2)
    assert shader.locate(8) == SourceLine("lib/deep/three.glsl", 3)
    assert shader.locate(9) == SourceLine("lib/two.glsl", 4)
    assert shader.locate(10) == SourceLine("lib/one.glsl", 3)
    assert shader.locate(11) == SourceLine("main.frag.glsl", 4)
    assert shader.locate(13) == SourceLine("main.frag.glsl", 6)
    # Every composed line comes from exactly the file line the map claims.
    for composed, origin in zip(lines_of(shader), shader.line_map, strict=True):
        original = (tmp_path / origin.file).read_text().split("\n")[origin.line - 1]
        assert composed == original or original.lstrip().startswith("#include")


def test_locate_out_of_range(tmp_path: Path) -> None:
    shader = write_tree(tmp_path, NESTED).compose("main.frag.glsl")
    with pytest.raises(IndexError):
        shader.locate(0)
    with pytest.raises(IndexError):
        shader.locate(14)


def test_include_relative_to_folder_then_root(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "post/blur.frag.glsl": (
                '#version 330\n#include "common.glsl"\n'
                '#include "util.glsl"\n#include "../up.glsl"\n'
            ),
            "post/common.glsl": "float post_common;\n",
            "common.glsl": "float root_common;\n",  # shadowed by post/common.glsl
            "util.glsl": "float root_util;\n",  # found only relative to the root
            "up.glsl": "float up;\n",
        },
    )
    shader = loader.compose("post/blur.frag.glsl")
    assert lines_of(shader) == [
        "#version 330",
        "float post_common;",
        "float root_util;",
        "float up;",
    ]
    assert shader.locate(2) == SourceLine("post/common.glsl", 1)
    assert shader.locate(3) == SourceLine("util.glsl", 1)
    assert shader.locate(4) == SourceLine("up.glsl", 1)


def test_diamond_include_included_once(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": '#version 330\n#include "b.glsl"\n#include "c.glsl"\nvoid main() {}\n',
            "b.glsl": '#include "common.glsl"\nfloat b() { return common(); }\n',
            "c.glsl": '#include "common.glsl"\nfloat c() { return common(); }\n',
            "common.glsl": "float common() { return 1.0; }\n",
        },
    )
    shader = loader.compose("a.glsl")
    assert shader.source.count("float common()") == 1
    texts = lines_of(shader)
    assert texts[1] == "float common() { return 1.0; }"
    assert shader.locate(2) == SourceLine("common.glsl", 1)
    # The second include becomes a comment mapped to its own directive line.
    assert texts[3].startswith("//") and "common.glsl" in texts[3]
    # and holds no directive: moderngl resolves '#include "..."' even in comments, and fails.
    assert "#include" not in shader.source
    assert shader.locate(4) == SourceLine("c.glsl", 1)
    assert shader.locate(5) == SourceLine("c.glsl", 2)
    assert shader.locate(6) == SourceLine("a.glsl", 4)


def test_include_cycle_shows_chain(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": '#version 330\n#include "b.glsl"\n',
            "b.glsl": '#include "c.glsl"\n',
            "c.glsl": '// c\n#include "b.glsl"\n',
        },
    )
    with pytest.raises(ShaderSourceError) as info:
        loader.compose("a.glsl")
    message = str(info.value)
    assert "a.glsl -> b.glsl -> c.glsl -> b.glsl" in message
    assert message.startswith("c.glsl:2:")


def test_include_cycle_back_to_top_level(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {"a.glsl": '#version 330\n#include "b.glsl"\n', "b.glsl": '#include "a.glsl"\n'},
    )
    with pytest.raises(ShaderSourceError, match=r"a\.glsl -> b\.glsl -> a\.glsl"):
        loader.compose("a.glsl")


def test_self_include_is_cycle(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": '#version 330\n#include "a.glsl"\n'})
    with pytest.raises(ShaderSourceError, match=r"a\.glsl -> a\.glsl"):
        loader.compose("a.glsl")


def chain_tree(root: Path, length: int) -> None:
    files = {"top.glsl": '#version 330\n#include "inc1.glsl"\n'}
    for i in range(1, length):
        files[f"inc{i}.glsl"] = f'#include "inc{i + 1}.glsl"\n'
    files[f"inc{length}.glsl"] = "float leaf;\n"
    write_tree(root, files)


def test_depth_cap(tmp_path: Path) -> None:
    chain_tree(tmp_path, 3)
    assert "float leaf;" in ShaderLoader(tmp_path, max_include_depth=3).compose("top.glsl").source
    with pytest.raises(ShaderSourceError, match="deeper than 2") as info:
        ShaderLoader(tmp_path, max_include_depth=2).compose("top.glsl")
    assert "top.glsl -> inc1.glsl -> inc2.glsl -> inc3.glsl" in str(info.value)
    assert info.value.file == "inc2.glsl"
    assert info.value.line == 1
    with pytest.raises(ShaderSourceError, match="deeper than 0"):
        ShaderLoader(tmp_path, max_include_depth=0).compose("top.glsl")


def test_default_depth_cap(tmp_path: Path) -> None:
    chain_tree(tmp_path, 8)
    assert "float leaf;" in ShaderLoader(tmp_path).compose("top.glsl").source
    chain_tree(tmp_path / "nine", 9)
    with pytest.raises(ShaderSourceError, match="deeper than 8"):
        ShaderLoader(tmp_path / "nine").compose("top.glsl")


def test_bad_max_include_depth() -> None:
    with pytest.raises(ValueError):
        ShaderLoader(Path("."), max_include_depth=-1)


def test_missing_include_names_file_and_line(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": '#version 330\n#include "lib/b.glsl"\n',
            "lib/b.glsl": '\n\n#include "gone.glsl"\n',
        },
    )
    with pytest.raises(ShaderSourceError) as info:
        loader.compose("a.glsl")
    assert info.value.file == "lib/b.glsl"
    assert info.value.line == 3
    assert str(info.value).startswith("lib/b.glsl:3: ")
    assert "'gone.glsl' not found" in str(info.value)


@pytest.mark.parametrize(
    "target", ["../secret.glsl", "lib/../../secret.glsl", "/etc/passwd", "./../x.glsl"]
)
def test_include_escaping_root(tmp_path: Path, target: str) -> None:
    (tmp_path / "secret.glsl").write_text("float secret;\n")
    root = tmp_path / "shaders"
    loader = write_tree(root, {"a.glsl": f'#version 330\n#include "{target}"\n'})
    with pytest.raises(ShaderSourceError, match=r"a\.glsl:2: .*(outside the shader root|relative)"):
        loader.compose("a.glsl")


def test_include_escaping_root_from_subfolder(tmp_path: Path) -> None:
    root = tmp_path / "shaders"
    (tmp_path / "secret.glsl").write_text("float secret;\n")
    loader = write_tree(
        root,
        {
            "a.glsl": '#version 330\n#include "sub/b.glsl"\n',
            "sub/b.glsl": '#include "../../secret.glsl"\n',
        },
    )
    with pytest.raises(ShaderSourceError, match=r"sub/b\.glsl:1: .*outside the shader root"):
        loader.compose("a.glsl")


@pytest.mark.parametrize("directive", ["#include <b.glsl>", "#include b.glsl", '#include "b.glsl'])
def test_malformed_include(tmp_path: Path, directive: str) -> None:
    loader = write_tree(
        tmp_path, {"a.glsl": f"#version 330\n{directive}\n", "b.glsl": "float b;\n"}
    )
    with pytest.raises(ShaderSourceError, match=r"a\.glsl:2: malformed include"):
        loader.compose("a.glsl")


def test_include_spacing_and_trailing_comment(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {"a.glsl": '#version 330\n  #  include  "b.glsl" // the b\n', "b.glsl": "float b;\n"},
    )
    assert lines_of(loader.compose("a.glsl")) == ["#version 330", "float b;"]


def test_commented_out_include_ignored(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {"a.glsl": '#version 330\n// #include "gone.glsl"\n/*\n#include "gone.glsl"\n*/\n'},
    )
    shader = loader.compose("a.glsl")
    assert shader.source.count('#include "gone.glsl"') == 2
    assert len(shader.line_map) == 5


def test_file_reads_are_cached(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path, {"a.glsl": '#version 330\n#include "b.glsl"\n', "b.glsl": "float b;\n"}
    )
    first = loader.compose("a.glsl")
    (tmp_path / "b.glsl").write_text("float changed;\n")
    assert loader.compose("a.glsl") == first
    assert "float changed;" in ShaderLoader(tmp_path).compose("a.glsl").source


# -- defines ----------------------------------------------------------------------------------

DEFINE_TREE = {
    "smooth_depth.frag.glsl": (
        "#version 330 core\n"  # 1
        "#define KERNEL_RADIUS 5\n"  # 2
        "#define SIGMA 2.5 // spatial sigma\n"  # 3
        "#define USE_BILATERAL 1\n"  # 4
        '#include "lib/filter.glsl"\n'  # 5
        "#define SQR(x) ((x) * (x))\n"  # 6
        "void main() {}\n"  # 7
    ),
    "lib/filter.glsl": (
        "// filter\n"  # 1
        "  #  define FILTER_MODE  linear\n"  # 2
        "float filter_weight();\n"  # 3
    ),
}


def test_define_override_in_place(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, DEFINE_TREE)
    plain = loader.compose("smooth_depth.frag.glsl")
    shader = loader.compose("smooth_depth.frag.glsl", {"KERNEL_RADIUS": 9, "SIGMA": 4.0})
    assert len(shader.line_map) == len(plain.line_map)
    assert shader.line_map == plain.line_map
    before, after = lines_of(plain), lines_of(shader)
    assert after[1] == "#define KERNEL_RADIUS 9"
    assert after[2] == "#define SIGMA 4.0 // spatial sigma"
    # Everything else is untouched.
    assert [a for i, a in enumerate(after) if i not in (1, 2)] == [
        b for i, b in enumerate(before) if i not in (1, 2)
    ]
    assert "#define USE_BILATERAL 1" in after


def test_define_override_in_include(tmp_path: Path) -> None:
    shader = write_tree(tmp_path, DEFINE_TREE).compose(
        "smooth_depth.frag.glsl", {"FILTER_MODE": "nearest"}
    )
    texts = lines_of(shader)
    index = texts.index("  #  define FILTER_MODE  nearest")
    assert shader.locate(index + 1) == SourceLine("lib/filter.glsl", 2)


def test_undeclared_define_lists_declared(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, DEFINE_TREE)
    with pytest.raises(ShaderSourceError) as info:
        loader.compose("smooth_depth.frag.glsl", {"FOO": 1})
    assert isinstance(info.value, ShaderDefineError)
    assert str(info.value) == (
        "'FOO' is not declared by smooth_depth.frag.glsl; "
        "declared: FILTER_MODE, KERNEL_RADIUS, SIGMA, USE_BILATERAL"
    )
    # Function-like macros cannot be overridden.
    with pytest.raises(ShaderDefineError, match="'SQR' is not declared"):
        loader.compose("smooth_depth.frag.glsl", {"SQR": 1})


def test_define_in_comment_not_declared(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path, {"a.glsl": "#version 330\n/*\n#define HIDDEN 1\n*/\n// #define ALSO 2\n"}
    )
    with pytest.raises(ShaderDefineError, match=r"declared: \(none\)"):
        loader.compose("a.glsl", {"HIDDEN": 2})


def test_define_without_value_and_repeated(tmp_path: Path) -> None:
    loader = write_tree(
        tmp_path,
        {
            "a.glsl": (
                "#version 330\n#define FLAG\n#ifdef X\n#define N 1\n#else\n#define N 2\n#endif\n"
            )
        },
    )
    texts = lines_of(loader.compose("a.glsl", {"FLAG": True, "N": 7}))
    assert texts[1] == "#define FLAG 1"
    assert texts[3] == "#define N 7"
    assert texts[5] == "#define N 7"


@pytest.mark.parametrize(
    ("value", "token"),
    [
        (True, "1"),
        (False, "0"),
        (2, "2"),
        (-3, "-3"),
        (2.0, "2.0"),
        (0.5, "0.5"),
        (1e-5, "1e-05"),
        (1.5e20, "1.5e+20"),
        ("vec3(1.0,0.0,0.0)", "vec3(1.0,0.0,0.0)"),
        ("nearest", "nearest"),
    ],
)
def test_define_value_formatting(
    tmp_path: Path, value: str | int | float | bool, token: str
) -> None:
    assert format_define_value("X", value) == token
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\n#define X 0\n"})
    assert lines_of(loader.compose("a.glsl", {"X": value}))[1] == f"#define X {token}"


@pytest.mark.parametrize(
    "value",
    ["", "a b", "1\n#define Y 2", "1\t", "1//x", "1/*x*/", "a\\", "#x", float("nan"), float("inf")],
)
def test_bad_define_values_rejected(tmp_path: Path, value: str | float) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\n#define X 0\n"})
    with pytest.raises(ShaderDefineError):
        loader.compose("a.glsl", {"X": value})
    with pytest.raises(ValueError):  # ShaderDefineError is also a ValueError
        format_define_value("X", value)


def test_bad_define_value_type_rejected(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\n#define X 0\n"})
    bad: Any = [1]
    with pytest.raises(ShaderDefineError, match="unsupported value type"):
        loader.compose("a.glsl", {"X": bad})


def test_multiline_define_cannot_be_overridden(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, {"a.glsl": "#version 330\n#define X 1 + \\\n  2\n"})
    with pytest.raises(ShaderDefineError, match=r"a\.glsl:2: .*multi-line"):
        loader.compose("a.glsl", {"X": 3})


# -- compile logs ------------------------------------------------------------------------------


def test_translate_mesa_log(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, NESTED)
    shader = loader.compose("main.frag.glsl")
    log = (
        "0:7(12): error: `retrun' undeclared\n"
        "0:12(5): warning: unused value\n"
        "0:0(0): error: linking failed\n"
        "some other text\n"
    )
    assert loader.translate_compile_error(shader, log) == (
        "lib/deep/three.glsl:2: error: `retrun' undeclared\n"
        "main.frag.glsl:5: warning: unused value\n"
        "0:0(0): error: linking failed\n"
        "some other text\n"
    )


def test_translate_nvidia_log(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, NESTED)
    shader = loader.compose("main.frag.glsl")
    log = '0(9) : error C0000: syntax error, unexpected "}"\r\n0(99) : error C1000: out of range'
    assert loader.translate_compile_error(shader, log) == (
        'lib/two.glsl:4: error C0000: syntax error, unexpected "}"\r\n'
        "0(99) : error C1000: out of range"
    )


def test_translate_other_formats(tmp_path: Path) -> None:
    loader = write_tree(tmp_path, NESTED)
    shader = loader.compose("main.frag.glsl")
    assert (
        loader.translate_compile_error(shader, "ERROR: 0:10: 'one' : undeclared identifier\n")
        == "lib/one.glsl:3: ERROR: 'one' : undeclared identifier\n"
    )
    unknown = "Shader compile failed\n1:3(1): error: other source string\n"
    assert loader.translate_compile_error(shader, unknown) == unknown
    assert loader.translate_compile_error(shader, "") == ""


# -- default root -----------------------------------------------------------------------------


def test_default_root_is_shader_package() -> None:
    root = ShaderLoader().root
    assert root.is_dir()
    assert root.joinpath("__init__.py").is_file()
    assert root.name == "shaders"

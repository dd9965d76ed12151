"""Attack rows for every file reader (issue 15): bombs, lying headers, bad values, deep
nesting, bad encodings, huge templates, and names that would become paths outside --out.

Every row runs ``fabkit ARGS`` on one hostile file and asserts what tests/attack.py
promises: exit 2, one line naming the problem, nothing written, done in a few seconds.
The files are made once per module by :func:`build`, small on disk (see tests/hostile.py).
"""

from __future__ import annotations

import json
import warnings
import zipfile

import numpy as np
import pytest

from fabkit.toolpath.job import ToolpathJob, run_job
from tests import hostile as h
from tests.attack import assert_refused, case
from tests.conftest import EXAMPLES, ROOT, coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

TWO = EXAMPLES / "two_shapes.toml"
SECRET = "root:secret-first-line-of-another-file"
DIW = "marlin_diw_pneumatic"
COARSE = "--step 0.1 --diagonals 30"
SIZE = "--size 20"


def _design_rows() -> list:
    """Hostile design files, each against one command that reads designs."""
    refused = "cannot read design file"
    rows = [
        ("check {d_deflate}", (refused, "corrupt data in 'alpha'"), "deflate"),
        ("check {d_txt_member}", (refused, "notes.txt"), "txt-member"),
        ("plot {d_dir_member} --out {out}", (refused, "sub/alpha.npy"), "dir-member"),
        ("check {d_garbage_member}", (refused, "'alpha' is not an .npy array"), "garbage-member"),
        ("check {d_duplicate}", (refused, "appears twice"), "duplicate-member"),
        ("check {d_bzip2}", (refused, "compression method 12"), "bzip2-member"),
        ("check {d_many_members}", (refused, "more than the limit of 64 members"), "many-members"),
        ("check {d_complex}", (refused, "complex128", "expected real numbers"), "complex"),
        ("plot {d_object} --out {out}", (refused, "object", "'alpha'"), "object"),
        ("check {d_structured}", (refused, "'alpha'", "expected real numbers"), "structured"),
        ("check {d_bomb10g}", (refused, "more than the limit of", "'r'"), "bomb-10g"),
        (
            f"toolpath {{d_bomb10g}} {SIZE} --out {{out}}",
            (refused, "more than the limit of"),
            "bomb-10g-toolpath",
        ),
        ("simulate {d_bomb10g} --stimulus 1", (refused, "more than the limit of"), "bomb-sim"),
        ("energy {d_bomb10g}", (refused, "more than the limit of"), "bomb-energy"),
        ("check {d_stream}", (refused, "is compressed"), "compressible-stream"),
        ("check {d_lying}", (refused, "declares", "but holds"), "lying-header"),
        ("check {d_1e300}", ("beyond the plausible", "'alpha'"), "alpha-1e300"),
        ("plot {d_eps_1e300} --out {out}", ("beyond the plausible", "'eps'"), "eps-1e300"),
        ("check {d_u_1e300}", ("uniform grid", "'u'"), "u-1e300"),
        ("check {d_u_uneven}", ("uniform grid", "'u'"), "u-uneven"),
        ("check {d_empty_grid}", ("has no solved point", "grid 0 x 0"), "empty-grid"),
        ("plot {d_no_valid} --out {out}", ("has no solved point",), "no-valid"),
        ("check {d_huge_grid}", ("more than the limit of", "nodes"), "huge-grid"),
        ("check {d_spec_deep}", ("nested deeper than",), "spec-deep"),
        ("check {d_spec_text}", ("not valid JSON", "embedded spec"), "spec-not-json"),
        ("plot {d_names} --out {out}", ("must be 1-64 letters", "x/../../name"), "name-up"),
        (
            "solve {spec} --out {out}.npz --diagonals 1100 --quadrants 1,1",
            ("a design file may hold",),
            "solve-grid",
        ),
        ("run {spec} --out {out} --diagonals 20000", ("more than the 4 GiB limit",), "run-grid"),
        ("run {spec_name_up} --out {out}", ("must be 1-64 letters", "x/../../name"), "run-name"),
        ("check {d_names_abs} ", ("must be 1-64 letters", "/tmp/fabkit"), "name-absolute"),
        (
            f"channels {{d_names}} --baromorph {{channels}} {SIZE} --out {{out}}",
            ("must be 1-64 letters",),
            "name-channels",
        ),
        (
            f"export {{d_complex}} --machine dmd_photoalign --format laser -o {{out}} {SIZE}",
            ("expected real numbers",),
            "export-complex",
        ),
    ]
    return [
        case(args, *says, outputs=("{out}",), id=f"files-design-{name}")
        for args, says, name in rows
    ]


def _toolpath_rows() -> list:
    rows = [
        ("t_bomb10g", ("more than the limit of", "'xyz'"), "bomb"),
        ("t_1e300", ("beyond the plausible", "'xyz'"), "1e300"),
        ("t_complex", ("expected real numbers",), "complex"),
        ("t_meta_deep", ("nested deeper than",), "meta-deep"),
        ("t_kind", ("refers to a missing layer or an unknown kind",), "kind-negative"),
        ("t_lying", ("declares", "but holds"), "lying-header"),
        ("t_json_deep", ("nested deeper than",), "json-deep"),
        ("t_json_huge", ("more than the limit of",), "json-huge"),
        ("t_many_moves", ("moves, more than the limit of",), "many-moves"),
    ]
    return [
        case(
            f"export {{{key}}} --machine {DIW} --format gcode -o {{out}}.gcode",
            *says,
            outputs=("{out}.gcode",),
            id=f"files-toolpath-{name}",
        )
        for key, says, name in rows
    ]


def _data_rows() -> list:
    """Height maps and meshes, each read through a spec by spec, solve or run."""
    rows = [
        ("spec {s_npy_1e300}", ("beyond the plausible", "h_1e300.npy"), "npy-1e300"),
        ("spec {s_npy_lying}", ("declares", "but holds"), "npy-lying-header"),
        ("spec {s_npy_huge}", ("nodes per side", "h_huge.npy"), "npy-huge-shape"),
        ("spec {s_npy_object}", ("expected real numbers",), "npy-object"),
        ("spec {s_npy_complex}", ("expected real numbers",), "npy-complex"),
        ("spec {s_npy_empty}", ("nodes per side",), "npy-0x0"),
        ("spec {s_npz_bomb}", ("more than the limit of",), "npz-bomb"),
        ("spec {s_png_header}", ("nodes per side", "h_header.png"), "png-header-bomb"),
        ("spec {s_png_bomb}", ("nodes per side", "h_bomb.png"), "png-bomb"),
        ("spec {s_csv_huge}", ("more than the limit of", "h_huge.csv"), "csv-huge"),
        ("spec {s_csv_1e300}", ("beyond the plausible",), "csv-1e300"),
        ("spec {s_csv_symlink}", ("is not a grid of numbers", "row 1"), "csv-symlink"),
        ("spec {s_stl_declared}", ("not a readable mesh",), "stl-declared-faces"),
        ("spec {s_stl_huge}", ("more than the limit of", "m_huge.stl"), "stl-huge"),
        ("spec {s_ply_declared}", ("contains no triangles",), "ply-declared-vertices"),
        ("spec {s_stl_1e300}", ("beyond the plausible",), "stl-1e300"),
        ("spec {s_stl_overlap}", ("more than the limit of", "grid node"), "stl-overlap"),
        (f"solve {{s_npy_lying}} --out {{out}}.npz {COARSE}", ("but holds",), "solve-npy-lying"),
        (f"run {{s_png_bomb}} --out {{out}} {COARSE}", ("nodes per side",), "run-png-bomb"),
    ]
    return [case(args, *says, id=f"files-data-{name}") for args, says, name in rows]


def _toml_rows() -> list:
    """TOML files of every kind: nested too deep, not UTF-8, too large."""
    deep = "nested deeper than"
    rows = [
        ("spec {toml_array}", (deep,), "spec-array"),
        ("spec {toml_inline}", (deep,), "spec-inline"),
        ("spec {toml_dotted}", (deep,), "spec-dotted"),
        ("spec {toml_header}", (deep,), "spec-header"),
        ("spec {toml_latin1}", ("not UTF-8",), "spec-latin1"),
        ("spec {toml_huge}", ("more than the limit of",), "spec-huge"),
        ("solve {toml_array} --out {out}.npz", (deep,), "solve-array"),
        ("run {spec} --out {out} --process {toml_array}", (deep, "toml_array.toml"), "process"),
        ("run {spec} --out {out} --process {toml_latin1}", ("not UTF-8",), "process-enc"),
        ("run {spec} --out {out} --machine {toml_inline}", (deep,), "machine"),
        ("run {spec} --out {out} --machine {toml_latin1}", ("not UTF-8",), "machine-enc"),
        ("run {spec} --out {out} --machine {toml_huge}", ("more than",), "machine-huge"),
        (
            f"channels {{design}} --baromorph {{toml_array}} {SIZE} --out {{out}}",
            (deep, "toml_array.toml"),
            "baromorph",
        ),
        (
            "run {spec} --out {out} --baromorph {toml_latin1} --format dxf",
            ("not UTF-8",),
            "baromorph-enc",
        ),
        ("swimmer {toml_dotted} --out {out}", (deep,), "swimmer"),
        ("swimmer {toml_latin1} --out {out}", ("not UTF-8",), "swimmer-enc"),
        ("toolpath {toml_header} --out {out}", (deep,), "director"),
        ("toolpath {toml_huge} --out {out}", ("more than the limit of",), "director-huge"),
    ]
    return [case(args, *says, id=f"files-toml-{name}") for args, says, name in rows]


def _profile_rows() -> list:
    """Machine profiles whose G-code templates would render huge or odd lines."""
    rows = [
        ("m_width", ("expected plain {", "{bed_c"), "template-width"),
        ("m_nested", ("expected plain {",), "template-nested"),
        ("m_conversion", ("expected plain {",), "template-conversion"),
        ("m_long", ("expected at most 16384 characters", "got 200041"), "template-long"),
    ]
    send = "send {gcode} --port sim://marlin?baud=0&time_scale=0 --machine {m_width}"
    return [
        case(send, "expected plain {", outputs=(), id="files-profile-send"),
        *[
            case(
                f"export {{toolpath}} --machine {{{key}}} --format gcode -o {{out}}.gcode",
                *says,
                outputs=("{out}.gcode",),
                id=f"files-profile-{name}",
            )
            for key, says, name in rows
        ],
    ]


def _other_rows() -> list:
    geometry = (
        "export {design} --machine laser_cutter --format dxf -o {out}.dxf --size 60 --geometry {}"
    )
    rows = [
        case(
            geometry.replace("{}", "{geo_deep}"),
            "nested deeper than",
            outputs=("{out}.dxf",),
            id="files-geojson-deep",
        ),
        case(
            geometry.replace("{}", "{geo_huge}"),
            "more than the limit of",
            outputs=("{out}.dxf",),
            id="files-geojson-huge",
        ),
        case(
            "toolpath {grid_bomb} --out {out}",
            "more than the limit of",
            id="files-director-grid-bomb",
        ),
        case(
            "toolpath {grid_complex} --out {out}",
            "expected real numbers",
            id="files-director-grid-complex",
        ),
        case(
            "swimmer {swimmer_stations} --out {out}",
            "more than the limit of",
            "stations",
            id="files-swimmer-stations",
        ),
        case(
            "swimmer {swimmer_rings} --out {out}",
            "more than the limit of",
            "hydrodynamics.rings",
            id="files-swimmer-rings",
        ),
        case(
            "channels {director_eps} --baromorph {baromorph_pitch} --out {out}",
            "leaves walls of",
            "pitch_mm",
            id="files-baromorph-pitch",
        ),
        case(
            "toolpath --director phi --shape disc:10 --layers 100000 --out {out}",
            "a toolpath file holds",
            "--layers 100000",
            id="files-toolpath-layers",
        ),
        case(
            f"toolpath {{design}} {SIZE} --process {{process_tiny}} --out {{out}}",
            "road widths of",
            id="files-process-tiny-road",
        ),
    ]
    return rows


CASES = [
    *_design_rows(),
    *_toolpath_rows(),
    *_data_rows(),
    *_toml_rows(),
    *_profile_rows(),
    *_other_rows(),
]


# ---------------------------------------------------------------------------- the files


def _spec_with_surface(geometry: dict) -> str:
    """two_shapes.toml whose bump is replaced by ``geometry`` (an inline TOML table)."""
    inline = ", ".join(f"{k} = {json.dumps(v)}" for k, v in geometry.items())
    text = TWO.read_text()
    old = 'geometry = { kind = "graph", z = "exp(-(x**2 + y**2/4))" }'
    assert old in text
    return text.replace(old, f"geometry = {{ {inline} }}")


def _design_files(folder, design) -> dict:
    """Hostile variants of a valid coarse design."""
    arrays = h.arrays_of(design)
    valid = arrays["valid"]
    alpha = arrays["alpha"]
    spec = h.spec_json_of(design)
    named = json.loads(json.dumps(spec))
    named["surfaces"][2]["name"] = "x/../../name"
    absolute = json.loads(json.dumps(spec))
    absolute["surfaces"][1]["name"] = "/tmp/fabkit-attack"
    uneven = arrays["u"].copy()
    uneven[1] += 0.3 * (uneven[2] - uneven[1])
    nu, nv = valid.shape
    files = {
        "d_deflate": h.corrupt_deflate(folder / "deflate.npz", design, "alpha"),
        "d_txt_member": h.with_members(folder / "txt.npz", design, **{"notes.txt": b"hello"}),
        "d_dir_member": h.with_members(
            folder / "dir.npz", design, **{"sub/alpha.npy": h.npy_bytes(alpha)}
        ),
        "d_garbage_member": h.with_members(folder / "garbage_member.npz", design),
        "d_complex": h.edited_npz(folder / "complex.npz", design, alpha=alpha.astype(complex)),
        "d_object": h.edited_npz(folder / "object.npz", design, alpha=alpha.astype(object)),
        "d_structured": h.edited_npz(
            folder / "structured.npz",
            design,
            alpha=np.zeros(alpha.shape, dtype=[("a", "<f8"), ("b", "<f8")]),
        ),
        "d_bomb10g": h.declared_size(folder / "bomb10g.npz", design, "r", 10 * h.GB),
        "d_stream": h.compressible_stream(
            folder / "stream.npz", design, "alpha", 900 << 20, (900 << 17,)
        ),
        "d_1e300": h.edited_npz(
            folder / "alpha_1e300.npz", design, alpha=np.where(valid, 1e300, alpha)
        ),
        "d_eps_1e300": h.edited_npz(
            folder / "eps_1e300.npz", design, eps=np.where(valid, -1e300, arrays["eps"])
        ),
        "d_u_1e300": h.edited_npz(folder / "u_1e300.npz", design, u=arrays["u"] * 1e300),
        "d_u_uneven": h.edited_npz(folder / "u_uneven.npz", design, u=uneven),
        "d_empty_grid": h.edited_npz(
            folder / "empty.npz",
            design,
            u=np.zeros(0),
            v=np.zeros(0),
            valid=np.zeros((0, 0), bool),
            alpha=np.zeros((0, 0)),
            beta=np.zeros((0, 0)),
            eps=np.zeros((1, 0, 0)),
            r=np.zeros((3, 0, 0, 2)),
            n=np.zeros((3, 0, 0, 2)),
            error=np.zeros((0, 0)),
        ),
        "d_no_valid": h.edited_npz(folder / "no_valid.npz", design, valid=np.zeros_like(valid)),
        "d_spec_deep": h.with_spec(folder / "spec_deep.npz", design, h.deep_json(100_000)),
        "d_spec_text": h.with_spec(folder / "spec_text.npz", design, "[material"),
        "d_names": h.with_spec(folder / "names.npz", design, named),
        "d_names_abs": h.with_spec(folder / "names_abs.npz", design, absolute),
    }
    members = {f"{k}.npy": h.npy_bytes(v) for k, v in arrays.items()}
    garbage = dict(members, **{"alpha.npy": b"this is not an npy file at all"})
    files["d_garbage_member"] = h.write_npz(folder / "garbage_member.npz", garbage)
    h.write_npz(folder / "duplicate.npz", members)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with zipfile.ZipFile(folder / "duplicate.npz", "a") as archive:
            archive.writestr("alpha.npy", members["alpha.npy"])
    files["d_duplicate"] = folder / "duplicate.npz"
    h.write_npz(folder / "bzip2.npz", members)
    with zipfile.ZipFile(folder / "bzip2.npz", "w", zipfile.ZIP_BZIP2) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    files["d_bzip2"] = folder / "bzip2.npz"
    many = dict(members, **{f"extra{k}.npy": h.npy_bytes(np.zeros(1)) for k in range(300)})
    files["d_many_members"] = h.write_npz(folder / "many.npz", many)
    lying = dict(members, **{"alpha.npy": h.npy_header((100_000, 100_000)) + bytes(64)})
    files["d_lying"] = h.write_npz(folder / "lying.npz", lying)
    big = 2100  # 4.4 million nodes; bool arrays keep every member below the ratio check
    shapes = {"valid": (big, big), "alpha": (big, big), "beta": (big, big)}
    shapes.update({"eps": (1, big, big), "r": (1, big, big, 2), "n": (1, big, big, 2)})
    files["d_huge_grid"] = h.declared_npz(
        folder / "huge_grid.npz",
        {key: (shape, "|b1") for key, shape in shapes.items()},
        u=np.arange(big) - big // 2,
        v=np.arange(big) - big // 2,
        stimuli=np.zeros((1, 1)),
        spec=arrays["spec"],
    )
    return files


def _channels(arrays: dict) -> list[str]:
    """The per-vertex channel arrays of a saved toolpath (format 2: ``channel_<name>``)."""
    return [key for key in arrays if key.startswith("channel_")]


def _toolpath_files(folder, toolpath) -> dict:
    arrays = h.arrays_of(toolpath)
    xyz = arrays["xyz"]
    n = 300_000
    many = {
        **arrays,
        "layer_z": np.zeros(1),
        "layer_height": np.full(1, 0.2),
        "move_start": np.arange(0, 2 * n + 1, 2, dtype=np.int64),
        "move_kind": np.zeros(n, np.int8),
        "move_layer": np.zeros(n, np.int32),
        "xyz": np.zeros((2 * n, 3)),
        **{k: np.ones(2 * n) for k in ("width", "speed", "flow", *_channels(arrays))},
    }
    kinds = arrays["move_kind"].copy()
    kinds[0] = -1
    members = {f"{k}.npy": h.npy_bytes(v) for k, v in arrays.items()}
    members["xyz.npy"] = h.npy_header((10**9, 3)) + bytes(64)
    files = {
        "t_bomb10g": h.declared_size(folder / "t_bomb.npz", toolpath, "xyz", 10 * h.GB),
        "t_1e300": h.edited_npz(folder / "t_1e300.npz", toolpath, xyz=xyz * 1e300),
        "t_complex": h.edited_npz(folder / "t_complex.npz", toolpath, xyz=xyz.astype(complex)),
        "t_meta_deep": h.edited_npz(
            folder / "t_meta.npz", toolpath, meta=np.array(h.deep_json(100_000))
        ),
        "t_kind": h.edited_npz(folder / "t_kind.npz", toolpath, move_kind=kinds),
        "t_lying": h.write_npz(folder / "t_lying.npz", members),
        "t_many_moves": h.write_npz(
            folder / "t_many.npz", {f"{k}.npy": h.npy_bytes(v) for k, v in many.items()}
        ),
    }
    (folder / "t_deep.json").write_text(h.deep_json(100_000))
    files["t_json_deep"] = folder / "t_deep.json"
    files["t_json_huge"] = h.sparse(folder / "t_huge.json", 10 * h.GB, b'{"format": ')
    return files


def _data_files(folder) -> dict:
    """Height maps and meshes, and a spec using each (keys s_*)."""
    z = np.zeros((12, 12))
    (folder / "secret.txt").write_text(f"{SECRET}\nmore\n")
    data = {
        "h_1e300.npy": lambda p: np.save(p, np.full((12, 12), 1e300)),
        "h_lying.npy": lambda p: h.lying_npy(p, (2000, 2000)),
        "h_huge.npy": lambda p: h.lying_npy(p, (30_000, 30_000)),
        "h_object.npy": lambda p: np.save(p, z.astype(object), allow_pickle=True),
        "h_complex.npy": lambda p: np.save(p, z.astype(complex)),
        "h_empty.npy": lambda p: np.save(p, np.zeros((0, 0))),
        "h_bomb.npz": lambda p: h.declared_size(
            p, h.write_npz(folder / "h_base.npz", {"z.npy": h.npy_bytes(z)}), "z", 10 * h.GB
        ),
        "h_header.png": lambda p: h.png_header(p, 100_000, 100_000),
        "h_bomb.png": lambda p: h.png_bomb(p, 12_000),
        "h_huge.csv": lambda p: h.sparse(p, 10 * h.GB, b"0,0,0\n"),
        "h_1e300.csv": lambda p: p.write_text("\n".join([",".join(["1e300"] * 12)] * 12)),
        "h_link.csv": lambda p: h.symlink(p, folder / "secret.txt"),
        "m_declared.stl": lambda p: h.stl_declaring(p, 10**9),
        "m_huge.stl": lambda p: h.sparse(p, 10 * h.GB, b"solid s\n"),
        "m_declared.ply": lambda p: h.ply_declaring(p, 10**12, 10**12),
        "m_1e300.stl": lambda p: h.ascii_stl(
            p, np.array([[[0, 0, 0], [1e300, 0, 0], [0, 1e300, 0]]] * 3, float)
        ),
        "m_overlap.stl": _overlapping_mesh,
    }
    files = {}
    for name, make in data.items():
        make(folder / name)
        stem = name.replace(".", "_").replace("h_", "s_", 1).replace("m_", "s_", 1)
        key = {
            "s_1e300_npy": "s_npy_1e300",
            "s_lying_npy": "s_npy_lying",
            "s_huge_npy": "s_npy_huge",
            "s_object_npy": "s_npy_object",
            "s_complex_npy": "s_npy_complex",
            "s_empty_npy": "s_npy_empty",
            "s_bomb_npz": "s_npz_bomb",
            "s_header_png": "s_png_header",
            "s_bomb_png": "s_png_bomb",
            "s_huge_csv": "s_csv_huge",
            "s_1e300_csv": "s_csv_1e300",
            "s_link_csv": "s_csv_symlink",
            "s_declared_stl": "s_stl_declared",
            "s_huge_stl": "s_stl_huge",
            "s_declared_ply": "s_ply_declared",
            "s_1e300_stl": "s_stl_1e300",
            "s_overlap_stl": "s_stl_overlap",
        }[stem]
        if name.startswith("m_"):
            geometry = {"kind": "mesh", "file": name}
        else:
            geometry = {"kind": "heightmap", "file": name, "extent": [-2, 2, -2, 2]}
        (folder / f"{key}.toml").write_text(_spec_with_surface(geometry))
        files[key] = folder / f"{key}.toml"
    return files


def _overlapping_mesh(path) -> None:
    """A fan of 1999 long thin triangles from one corner to a 2000-level diagonal: a
    height field, but rasterising it by bounding boxes would visit about 10^9 grid nodes."""
    side = 2000
    diagonal = np.stack([np.arange(side), np.arange(side), np.zeros(side)], -1).astype(float)
    vertices = np.concatenate([diagonal, [[side - 1.0, 0.0, 0.0]]])
    triangles = [(k, k + 1, side) for k in range(side - 1)]
    h.ascii_stl(path, vertices[np.array(triangles)])


def _toml_files(folder) -> dict:
    files = {
        "toml_array": h.deep_toml("array", 100_000),
        "toml_inline": h.deep_toml("inline", 100_000),
        "toml_dotted": h.deep_toml("dotted", 100_000),
        "toml_header": h.deep_toml("header", 100_000),
    }
    paths = {}
    for key, text in files.items():
        (folder / f"{key}.toml").write_text(text)
        paths[key] = folder / f"{key}.toml"
    (folder / "latin1.toml").write_bytes('[material]\nfeatures = ["é"]\n'.encode("latin-1"))
    paths["toml_latin1"] = folder / "latin1.toml"
    paths["toml_huge"] = h.sparse(folder / "huge.toml", 10 * h.GB, b"# huge\n")
    return paths


def _profile_files(folder) -> dict:
    base = (ROOT / "machines" / f"{DIW}.toml").read_text()
    line = "G1 Z{travel_lift_mm} F{z_feed_mm_min}"
    assert line in base
    variants = {
        "m_width": "M140 S{bed_c:>100000000}",
        "m_nested": "M140 S{bed_c:{nozzle_c}}",
        "m_conversion": "M140 S{bed_c!r}",
        "m_long": "G4 P0 ; " + "x" * 200_000,
    }
    (folder / "sheet.gcode").write_text("G90\nG1 X10 Y10 F600\n")
    paths = {"gcode": folder / "sheet.gcode"}
    for key, text in variants.items():
        (folder / f"{key}.toml").write_text(base.replace(line, text, 1))
        paths[key] = folder / f"{key}.toml"
    return paths


def _other_files(folder, design) -> dict:
    (folder / "geo_deep.json").write_text(h.deep_json(100_000))
    grid = {"theta": np.zeros((10, 10)), "mask": np.ones((10, 10), bool), "pixel_mm": np.array(1.0)}
    h.write_npz(folder / "grid.npz", {f"{k}.npy": h.npy_bytes(v) for k, v in grid.items()})
    h.declared_size(folder / "grid_bomb.npz", folder / "grid.npz", "theta", 10 * h.GB)
    h.edited_npz(folder / "grid_complex.npz", folder / "grid.npz", theta=grid["theta"] + 0j)
    for key in ("grid_bomb", "grid_complex"):
        (folder / f"{key}.toml").write_text(f'[director]\ngrid = "{key}.npz"\n')
    swimmer = (EXAMPLES / "swimmer.toml").read_text()
    (folder / "swimmer_stations.toml").write_text(
        swimmer.replace("stations = 6", "stations = 1000000000")
    )
    (folder / "swimmer_rings.toml").write_text(swimmer.replace("rings = 20", "rings = 100000"))
    channels = (EXAMPLES / "baromorph_channels.toml").read_text()
    (folder / "baromorph_pitch.toml").write_text(
        channels.replace("pitch_mm = 3.0", "pitch_mm = 1e-300")
    )
    process = (EXAMPLES / "directors" / "process_lce.toml").read_text()
    (folder / "process_tiny.toml").write_text(
        process.replace("road_width_mm = 0.4", "road_width_mm = 1e-300")
    )
    (folder / "director_eps.toml").write_text(
        '[director]\ntheta = "arctan2(y, x)"\nshape = "disc:20"\neps = "0.4"\n'
    )
    two = TWO.read_text()
    (folder / "spec_name_up.toml").write_text(two.replace('name = "bump"', 'name = "x/../../name"'))
    return {
        "spec_name_up": folder / "spec_name_up.toml",
        "director_eps": folder / "director_eps.toml",
        "geo_deep": folder / "geo_deep.json",
        "geo_huge": h.sparse(folder / "geo_huge.json", 10 * h.GB, b"{"),
        "grid_bomb": folder / "grid_bomb.toml",
        "grid_complex": folder / "grid_complex.toml",
        "swimmer_stations": folder / "swimmer_stations.toml",
        "swimmer_rings": folder / "swimmer_rings.toml",
        "baromorph_pitch": folder / "baromorph_pitch.toml",
        "process_tiny": folder / "process_tiny.toml",
    }


def build(folder) -> dict[str, str]:
    """Every input of the rows above, made in ``folder``."""
    design = folder / "design.npz"
    coarse_design().save(design)
    run_job(ToolpathJob(director="arctan2(y, x)", shape="disc:5", out=str(folder / "toolpath")))
    toolpath = folder / "toolpath" / "toolpath.npz"
    places = {
        "design": design,
        "toolpath": toolpath,
        **_design_files(folder, design),
        **_toolpath_files(folder, toolpath),
        **_data_files(folder),
        **_toml_files(folder),
        **_profile_files(folder),
        **_other_files(folder, design),
    }
    return {key: str(path) for key, path in places.items()}


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    return build(folder)


@pytest.mark.parametrize("bad", CASES)
def test_a_hostile_file_is_refused_in_one_line(bad, places, run_cli, tmp_path):
    """...and prints no warning (on the command line, a second line on stderr) and never
    quotes another file."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        err = assert_refused(bad, places, tmp_path, run_cli)
    assert SECRET not in err
    assert [f"{w.category.__name__}: {w.message}" for w in caught] == []

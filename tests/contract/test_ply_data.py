"""The one PLY reader both sides use (igs_contract.ply_data) and the compressed PLY decoder.

Standard layer files written by plyfile (an independent writer) in binary little-endian, binary
big-endian and ASCII read the same values on the backend and the add-on side; every scalar type reads;
elements before ``vertex`` are skipped. The compressed PLY in tests/data was written by PlayCanvas's
splat-transform 2.7.1 (``splat-transform src.ply out.compressed.ply``, source columns from
:func:`source_columns`), and ``*.decompressed.ply`` is that tool's own decoding of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from intrinsic_splats.igs_blender.errors import UserError  # noqa: E402
from intrinsic_splats.igs_blender.ply_io import read_splat_ply  # noqa: E402
from plyfile import PlyData, PlyElement

from backend.core.errors import IGSError
from backend.splats.ply import read_ply
from igs_contract import compressed_ply, layer_ply, ply_data, ply_header
from igs_contract.errors import ContractError
from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)
from tests.support.ply_columns import COMPRESSED, ENCODINGS, source_columns  # noqa: E402

DATA = Path(__file__).parents[1] / "data"
DECOMPRESSED = DATA / "splat_transform_2.7.1.decompressed.ply"


def write(path: Path, elements: list, encoding: str, comments=()) -> Path:
    PlyData(elements, comments=list(comments), **ENCODINGS[encoding]).write(str(path))
    return path


def test_the_fixture_still_matches_its_source():
    """The decompressed fixture is the source within the format's quantisation (so the seed's columns
    are what the compressed file holds)."""
    src, theirs = source_columns(), ply_data.read_elements(DECOMPRESSED)["vertex"]
    order = _match(theirs, src)
    np.testing.assert_allclose(theirs["x"], src["x"][order], atol=0.01)


def _match(decoded: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Index into ``src`` of each decoded row (the writer reorders Gaussians in Morton order)."""
    a = np.stack([decoded[k] for k in "xyz"], axis=1).astype(np.float64)
    b = np.stack([src[k] for k in "xyz"], axis=1).astype(np.float64)
    order = ((a[:, None] - b[None]) ** 2).sum(-1).argmin(axis=1)
    assert len(np.unique(order)) == len(src)
    return order


@pytest.mark.parametrize("encoding", ["le", "be", "ascii"])
def test_every_encoding_reads_the_same_on_both_sides(tmp_path, encoding):
    src = source_columns(n=40, sh_degree=2, seed=3)
    src["opacity"] = np.linspace(-3, 3, 40)
    eps = np.zeros(40, dtype=[("eps2d", "<f4")])
    eps["eps2d"] = np.linspace(0.05, 0.3, 40)
    rec = np.empty(40, dtype=src.dtype.descr + eps.dtype.descr)
    for k in src.dtype.names:
        rec[k] = src[k]
    rec["eps2d"] = eps["eps2d"]
    path = write(tmp_path / f"{encoding}.ply", [PlyElement.describe(rec, "vertex")], encoding,
                 comments=layer_ply.header_comments("residual", "sh", "linear", 2))
    assert ply_header.read_header(path).format == {"le": "binary_little_endian", "be": "binary_big_endian",
                                                   "ascii": "ascii"}[encoding]
    data = ply_data.read_layer(path)
    assert data.layout.kind == "residual" and data.layout.low_pass and not data.compressed
    np.testing.assert_array_equal(data.arrays["means"], np.stack([src[k] for k in "xyz"], 1))
    np.testing.assert_array_equal(data.arrays["f_rest"][:, 5], src["f_rest_5"])
    np.testing.assert_array_equal(data.arrays["eps2d"], rec["eps2d"])

    addon = read_splat_ply(path)
    gs, info = read_ply(path)
    assert addon.kind == info.kind == "residual" and addon.sh_degree == gs.sh_degree == 2
    np.testing.assert_array_equal(addon.means, gs.means.detach().numpy())
    np.testing.assert_array_equal(addon.f_rest, gs.params["shN"].detach().numpy())
    np.testing.assert_array_equal(addon.opacity_logits, gs.params["opacity_logits"].detach().numpy())
    np.testing.assert_array_equal(addon.eps2d, gs.eps2d.detach().numpy())
    np.testing.assert_array_equal(addon.quats, data.arrays["rot"])


TYPED = {"char": ("i1", -128), "uchar": ("u1", 255), "short": ("i2", -32768), "ushort": ("u2", 65535),
         "int": ("i4", -2**31), "uint": ("u4", 2**32 - 1), "float": ("f4", 1.5), "double": ("f8", 1e300)}
ALIASES = {"int8": "char", "uint8": "uchar", "int16": "short", "uint16": "ushort", "int32": "int",
           "uint32": "uint", "float32": "float", "float64": "double"}


@pytest.mark.parametrize("encoding", ["le", "be", "ascii"])
def test_every_scalar_type_and_elements_around_the_vertex(tmp_path, encoding):
    """Values at the ends of each type's range read exactly; a face element with lists and a scalar
    element before 'vertex', and one after, are skipped."""
    n = 3
    rec = np.zeros(n, dtype=[(name, code) for name, (code, _) in TYPED.items()])
    for name, (_, extreme) in TYPED.items():
        rec[name] = [extreme, 0, 1]
    faces = np.empty(2, dtype=[("vertex_indices", "O"), ("flag", "u1")])
    faces["vertex_indices"] = [np.array([0, 1, 2], "i4"), np.array([2, 1, 0, 1, 2], "i4")]
    faces["flag"] = [7, 9]
    chunk = np.ones(4, dtype=[("min_x", "f4"), ("max_x", "f8")])
    after = np.ones(5, dtype=[("a", "i2")])
    path = write(tmp_path / "types.ply", [PlyElement.describe(faces, "face"), PlyElement.describe(chunk, "chunk"),
                                          PlyElement.describe(rec, "vertex"), PlyElement.describe(after, "after")],
                 encoding)
    header = ply_header.read_header(path)
    got = ply_data.read_elements(path, ("vertex", "chunk"), header)
    assert set(got) == {"vertex", "chunk"} and len(got["chunk"]) == 4
    for name, (code, _) in TYPED.items():
        assert got["vertex"].dtype[name] == np.dtype(code).newbyteorder("=")
        np.testing.assert_array_equal(got["vertex"][name], rec[name], err_msg=name)

    # the PLY spec's sized aliases name the same types
    text = path.read_bytes()
    for alias, name in ALIASES.items():
        text = text.replace(f"property {name} {name}\n".encode(), f"property {alias} {name}\n".encode(), 1)
    aliased = tmp_path / "aliases.ply"
    aliased.write_bytes(text)
    assert b"property uint8 uchar" in text
    np.testing.assert_array_equal(ply_data.read_elements(aliased)["vertex"], got["vertex"])


@pytest.mark.parametrize("encoding", ["le", "ascii"])
def test_a_list_in_the_vertex_element_is_one_error_naming_the_file(tmp_path, encoding):
    rec = np.empty(2, dtype=[("x", "f4"), ("ids", "O")])
    rec["x"] = [1, 2]
    rec["ids"] = [np.array([1], "i4"), np.array([1, 2], "i4")]
    path = write(tmp_path / "lists.ply", [PlyElement.describe(rec, "vertex")], encoding)
    with pytest.raises(ContractError, match=r"lists\.ply: the 'vertex' element has list properties \(ids\)"):
        ply_data.read_elements(path)
    with pytest.raises(UserError, match="lists.ply"):
        read_splat_ply(path)
    with pytest.raises(IGSError, match="lists.ply"):
        read_ply(path)


@pytest.mark.parametrize("cut,match", [("ascii_short", "truncated PLY"), ("ascii_int", "not a uchar"),
                                       ("be_short", "truncated PLY"), ("list_short", "truncated PLY")])
def test_malformed_data_is_one_clean_error(tmp_path, cut, match):
    rec = np.zeros(4, dtype=[("x", "f4"), ("u", "u1")])
    if cut == "ascii_short":
        path = write(tmp_path / "a.ply", [PlyElement.describe(rec, "vertex")], "ascii")
        path.write_bytes(path.read_bytes().rstrip()[:-4])
    elif cut == "ascii_int":
        path = write(tmp_path / "a.ply", [PlyElement.describe(rec, "vertex")], "ascii")
        path.write_bytes(path.read_bytes().rstrip() + b".5\n")
    elif cut == "be_short":
        path = write(tmp_path / "a.ply", [PlyElement.describe(rec, "vertex")], "be")
        path.write_bytes(path.read_bytes()[:-3])
    else:
        faces = np.empty(1, dtype=[("ids", "O")])
        faces["ids"] = [np.arange(200, dtype="i4")]
        path = write(tmp_path / "a.ply", [PlyElement.describe(faces, "face"), PlyElement.describe(rec, "vertex")], "le")
        path.write_bytes(path.read_bytes()[:-700])
    with pytest.raises(ContractError, match=match) as err:
        ply_data.read_elements(path)
    assert str(path) in str(err.value)


def test_compressed_ply_decodes_as_its_writer_decodes_it():
    """Our decoder against splat-transform's own decoding of the same file: the same floats, except
    that an 8-bit opacity of 0 or 255 is a finite logit here (the tool writes -inf / inf)."""
    ours = ply_data.read_layer(COMPRESSED)
    theirs = ply_data.read_elements(DECOMPRESSED)["vertex"]
    assert ours.compressed and ours.layout.foreign and ours.layout.kind == "radiance" and ours.layout.space == "srgb"
    assert ours.layout.sh_degree == 1 and ours.layout.count == 300
    a = ours.arrays
    for group, names in layer_ply.GROUPS.items():
        if group != "opacity":
            np.testing.assert_array_equal(a[group], np.stack([theirs[k] for k in names], 1), err_msg=group)
    np.testing.assert_array_equal(a["f_rest"], np.stack([theirs[f"f_rest_{i}"] for i in range(9)], 1))
    finite = np.isfinite(theirs["opacity"])
    assert (~finite).sum() == 2  # the two saturated opacities of the source
    np.testing.assert_array_equal(a["opacity"][finite], theirs["opacity"][finite])
    np.testing.assert_allclose(np.abs(a["opacity"][~finite]), np.log(509.0), rtol=1e-6)
    assert np.all(np.sign(a["opacity"][~finite]) == np.sign(theirs["opacity"][~finite]))


def test_compressed_ply_is_its_source_within_the_quantisation():
    src = source_columns()
    got = ply_data.read_layer(COMPRESSED).arrays
    s = src[_match_arrays(got["means"], src)]
    chunk = ply_data.read_elements(COMPRESSED, ("chunk",))["chunk"]
    extent = max(float((chunk[f"max_{a}"] - chunk[f"min_{a}"]).max()) for a in "xyz")
    np.testing.assert_allclose(got["means"], np.stack([s[k] for k in "xyz"], 1), atol=extent / 1023 / 2 + 1e-6)
    scale_extent = max(float((chunk[f"max_scale_{a}"] - chunk[f"min_scale_{a}"]).max()) for a in "xyz")
    np.testing.assert_allclose(got["scales"], np.stack([s[f"scale_{i}"] for i in range(3)], 1),
                               atol=scale_extent / 1023 / 2 + 1e-6)
    color = lambda f_dc: 0.5 + layer_ply.C0 * f_dc  # noqa: E731
    np.testing.assert_allclose(color(got["f_dc"]), color(np.stack([s[f"f_dc_{i}"] for i in range(3)], 1)),
                               atol=float(max((chunk[f"max_{c}"] - chunk[f"min_{c}"]).max() for c in "rgb")) / 510 + 1e-6)
    sigmoid = lambda x: 1 / (1 + np.exp(-x.astype(np.float64)))  # noqa: E731
    np.testing.assert_allclose(sigmoid(got["opacity"]), sigmoid(s["opacity"]), atol=1 / 510 + 1e-6)
    q = np.stack([s[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.sign(q[np.arange(len(q)), np.abs(q).argmax(1)])[:, None]  # the format keeps the largest positive
    np.testing.assert_allclose(got["rot"], q, atol=2e-3)
    np.testing.assert_allclose(got["f_rest"], np.stack([s[f"f_rest_{i}"] for i in range(9)], 1),
                               atol=1 / 64 + 1e-6)


def _match_arrays(means: np.ndarray, src: np.ndarray) -> np.ndarray:
    rec = np.zeros(len(means), dtype=[(k, "f4") for k in "xyz"])
    for i, k in enumerate("xyz"):
        rec[k] = means[:, i]
    return _match(rec, src)


def test_compressed_ply_reads_on_both_sides():
    gs, info = read_ply(COMPRESSED)
    addon = read_splat_ply(COMPRESSED)
    assert info.foreign and info.kind == addon.kind == "radiance" and gs.sh_degree == addon.sh_degree == 1
    np.testing.assert_array_equal(addon.means, gs.means.detach().numpy())
    np.testing.assert_array_equal(addon.f_rest, gs.params["shN"].detach().numpy())
    albedo, _ = read_ply(COMPRESSED, kind="albedo")  # the DC colour as an albedo
    assert albedo.kind == "albedo" and albedo.sh_degree == 0


def _packed_file(path: Path, n: int, chunks: int | None = None, colours: bool = False, fmt="binary_little_endian"):
    """A compressed PLY built from the documented packing: every Gaussian at its chunk's max corner, scale
    at the min, the largest rotation component in slot ``i % 4``, colour (64, 128, 255) and opacity 0."""
    chunks = -(-n // 256) if chunks is None else chunks
    bounds = list(compressed_ply.BOUNDS) + (list(compressed_ply.COLOR_BOUNDS) if colours else [])
    chunk = np.zeros(chunks, dtype=[(b, "<f4") for b in bounds])
    chunk["min_x"], chunk["max_x"], chunk["max_y"], chunk["max_z"] = -1, 2, 3, 4
    for a in "xyz":
        chunk[f"min_scale_{a}"], chunk[f"max_scale_{a}"] = -5, -1
    if colours:
        for c in "rgb":
            chunk[f"min_{c}"], chunk[f"max_{c}"] = -1, 3
    vertex = np.zeros(n, dtype=[(p, "<u4") for p in compressed_ply.PACKED])
    vertex["packed_position"] = 0xFFFFFFFF  # all ones: the max corner
    vertex["packed_scale"] = 0
    mid = 511  # 10-bit code nearest to 0.5: a component near 0
    vertex["packed_rotation"] = (np.arange(n, dtype=np.uint32) % 4 << 30) | (mid << 20) | (mid << 10) | mid
    vertex["packed_color"] = (64 << 24) | (128 << 16) | (255 << 8) | 0
    header = ["ply", f"format {fmt} 1.0", f"element chunk {chunks}", *(f"property float {b}" for b in bounds),
              f"element vertex {n}", *(f"property uint {p}" for p in compressed_ply.PACKED), "end_header"]
    path.write_bytes(("\n".join(header) + "\n").encode() + chunk.tobytes() + vertex.tobytes())
    return path


@pytest.mark.parametrize("colours", [False, True])
def test_compressed_packing_from_its_description(tmp_path, colours):
    """Older files have no colour bounds: the 8-bit colour is the colour itself."""
    got = ply_data.read_layer(_packed_file(tmp_path / "p.ply", 300, colours=colours)).arrays
    np.testing.assert_allclose(got["means"], np.tile([2, 3, 4], (300, 1)))
    np.testing.assert_allclose(got["scales"], -5)
    rgb = np.array([64, 128, 255]) / 255
    shown = 0.5 + layer_ply.C0 * got["f_dc"]
    np.testing.assert_allclose(shown, np.tile(-1 + 4 * rgb if colours else rgb, (300, 1)), atol=1e-6)
    assert np.isfinite(got["opacity"]).all() and (1 / (1 + np.exp(-got["opacity"])) < 1 / 255).all()
    largest = np.abs(got["rot"]).argmax(1)
    np.testing.assert_array_equal(largest, np.arange(300) % 4)
    np.testing.assert_allclose(np.linalg.norm(got["rot"], axis=1), 1, atol=1e-6)


@pytest.mark.parametrize("case,match", [
    ("chunks", "2 chunks for 200 Gaussians; expected 1"),
    ("ascii", "a compressed PLY is binary_little_endian"),
    ("packed_float", "packed_position, packed_rotation, packed_scale, packed_color must be unsigned integer"),
])
def test_malformed_compressed_ply_is_one_error_on_both_sides(tmp_path, case, match):
    path = _packed_file(tmp_path / "c.ply", 200, chunks=2 if case == "chunks" else None,
                        fmt="binary_big_endian" if case == "ascii" else "binary_little_endian")
    if case == "ascii":  # an ASCII header over the same values: the format allows only little-endian
        path.write_bytes(path.read_bytes().replace(b"binary_big_endian", b"ascii", 1).split(b"end_header\n")[0]
                         + b"end_header\n" + b" ".join([b"0"] * 12 + [b"1"] * 4 * 200) + b"\n")
    if case == "packed_float":
        path.write_bytes(path.read_bytes().replace(b"property uint packed", b"property float packed"))
    with pytest.raises(ContractError, match=match):
        ply_data.read_layer(path)
    with pytest.raises(UserError, match="c.ply"):
        read_splat_ply(path)
    with pytest.raises(IGSError, match="c.ply"):
        read_ply(path)


def _mutate(rng: np.random.Generator, raw: bytes, limit: int) -> bytes:
    """Bytes flipped, the file cut, or junk inserted, at a position before ``limit``."""
    b = bytearray(raw)
    pos = int(rng.integers(0, limit))
    op = int(rng.integers(0, 3))
    if op == 0:
        for _ in range(int(rng.integers(1, 9))):
            b[int(rng.integers(0, limit))] = int(rng.integers(0, 256))
    elif op == 1:
        del b[pos:]
    else:
        b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64))).astype(np.uint8).tobytes()
    return bytes(b)


def test_fuzzed_compressed_and_ascii_files_end_in_a_value_or_one_clean_error(tmp_path):
    """Seeded byte mutations of a compressed and of an ASCII layer: ContractError or a valid read, never
    another exception."""
    ascii_path = write(tmp_path / "a.ply", [PlyElement.describe(source_columns(20, 1, 2), "vertex")], "ascii")
    rng = np.random.default_rng(33)
    outcomes = {"valid": 0, "clean": 0}
    for source in (COMPRESSED, ascii_path):
        raw = source.read_bytes()
        head = raw.index(b"end_header") + 11
        for i in range(150):
            path = tmp_path / f"m{i}.ply"
            path.write_bytes(_mutate(rng, raw, head if i % 2 else len(raw)))
            try:
                ply_data.read_layer(path)
            except ContractError:
                outcomes["clean"] += 1
            else:
                outcomes["valid"] += 1
    assert outcomes["clean"] > 50 and outcomes["valid"] > 10, outcomes

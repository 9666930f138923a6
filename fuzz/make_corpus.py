#!/usr/bin/env python3
"""Regenerates fuzz/corpus/<target>/: the seed corpora of the libFuzzer targets (docs/SECURITY.md).

Seeds are small: the valid samples of tests/data/samples, the malformed files of
tests/data/broken (both read from the repository, never copied from ../shared) and a few tiny
hand-made valid files per format. Multi-file inputs join their files with SPLIT (fuzz_util.h):
OBJ | m.mtl, glTF | b.bin, JSON | m.obj | m.ply | sky.hdr. scripts/fuzz.sh adds small extracts of
the shipped meshes (../shared/data/meshes) at run time, in its scratch copy of the corpus."""
import base64, json, os, shutil, struct, zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = os.path.join(ROOT, "tests", "data", "samples")
BROKEN = os.path.join(ROOT, "tests", "data", "broken")
OUT = os.path.join(ROOT, "fuzz", "corpus")
SPLIT = b"\n#--8<--\n"
MAX_SEED = 64 * 1024  # larger broken files (e.g. deep nesting) are left to the regression suite


def read(d, name):
    with open(os.path.join(d, name), "rb") as f:
        return f.read()


def put(target, name, data):
    d = os.path.join(OUT, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)


def broken(prefix, ext):
    for n in sorted(os.listdir(BROKEN)):
        if n.startswith(prefix) and n.endswith(ext) and os.path.getsize(os.path.join(BROKEN, n)) <= MAX_SEED:
            yield n, read(BROKEN, n)


shutil.rmtree(OUT, ignore_errors=True)

# ---------------------------------------------------------------- OBJ + MTL
obj = read(SAMPLES, "cube.obj").replace(b"mtllib cube.mtl", b"mtllib m.mtl")
put("fuzz_obj", "sample_cube", obj + SPLIT + read(SAMPLES, "cube.mtl"))
put("fuzz_obj", "sample_cube_no_mtl", read(SAMPLES, "cube.obj"))
for n, d in broken("obj_", ".obj"):
    put("fuzz_obj", "broken_" + n, d)
put("fuzz_obj", "tri", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
put("fuzz_obj", "quad_vt_vn_relative",
    "# relative indices, texcoords, normals, groups, smoothing\nmtllib m.mtl\no quad\n"
    "v -1 -1 0\nv 1 -1 0\nv 1 1 0 1\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
    "g front\ns 1\nusemtl mirror\nf -4/-4/-1 -3/-3/-1 -2/-2/-1 -1/-1/-1\ns off\nusemtl glass\nf 1//1 3//1 4//1\n"
    "l 1 2\np 3\n" + SPLIT.decode() +
    "newmtl mirror\nKa 0 0 0\nKd 0.1 0.1 0.1\nKs 1 1 1\nKe 0 0 0\nNs 1000\nillum 5\n"
    "newmtl glass\nKd 0 0 0\nNi 1.5\nd 0.1\nTr 0.9\nTf 0.9 0.8 0.7\nillum 7\nmap_Kd tex.png\n")
put("fuzz_obj", "broken_polygon_line_continuation", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\nf 1 2 \\\n 3 4 5\n")

# ---------------------------------------------------------------- PLY
for n in ("cube_ascii.ply", "cube_le.ply", "cube_be.ply"):
    put("fuzz_ply", "sample_" + n, read(SAMPLES, n))
for n, d in broken("ply_", ".ply"):
    put("fuzz_ply", "broken_" + n, d)
put("fuzz_ply", "tri_ascii", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
    "element face 1\nproperty list uchar int vertex_index\nend_header\n"
    "0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n")
hdr = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
       b"property double z\nelement tristrips 1\nproperty list int uint vertex_indices\nend_header\n")
put("fuzz_ply", "strip_le_double", hdr + b"".join(struct.pack("<3d", *v) for v in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)))
    + struct.pack("<i4I", 4, 0, 1, 2, 3))

# ---------------------------------------------------------------- glTF / GLB
put("fuzz_gltf", "sample_cube_embedded", read(SAMPLES, "cube_embedded.gltf"))
ext = read(SAMPLES, "cube_external.gltf").replace(b'"cube_external.bin"', b'"b.bin"')
put("fuzz_gltf", "sample_cube_external", ext + SPLIT + read(SAMPLES, "cube_external.bin"))
for n, d in broken("gltf_", ".gltf"):
    put("fuzz_gltf", "broken_" + n, d)
tri_pos = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
tri_idx = struct.pack("<3B", 0, 1, 2) + b"\0"


def tri_gltf(uri, mode=None, indexed=True):
    prim = {"attributes": {"POSITION": 0}}
    if indexed:
        prim["indices"] = 1
    if mode is not None:
        prim["mode"] = mode
    g = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}],
         "nodes": [{"mesh": 0, "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}],
         "meshes": [{"primitives": [prim]}],
         "buffers": [{"byteLength": len(tri_pos) + len(tri_idx)}],
         "bufferViews": [{"buffer": 0, "byteLength": len(tri_pos)},
                         {"buffer": 0, "byteOffset": len(tri_pos), "byteLength": 3}],
         "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                       {"bufferView": 1, "componentType": 5121, "count": 3, "type": "SCALAR"}]}
    if uri is not None:
        g["buffers"][0]["uri"] = uri
    return g


data_uri = "data:application/octet-stream;base64," + base64.b64encode(tri_pos + tri_idx).decode()
put("fuzz_gltf", "tri_data_uri", json.dumps(tri_gltf(data_uri)))
put("fuzz_gltf", "tri_fan_unindexed", json.dumps(tri_gltf(data_uri, mode=6, indexed=False)))
put("fuzz_gltf", "tri_external", json.dumps(tri_gltf("b.bin")).encode() + SPLIT + tri_pos + tri_idx)


def glb(g, binary):
    j = json.dumps(g).encode()
    j += b" " * (-len(j) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j
    if binary is not None:
        b = binary + b"\0" * (-len(binary) % 4)
        body += struct.pack("<II", len(b), 0x004E4942) + b
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


put("fuzz_glb", "sample_cube", read(SAMPLES, "cube.glb"))
for n, d in broken("glb_", ".glb"):
    put("fuzz_glb", "broken_" + n, d)
put("fuzz_glb", "tri", glb(tri_gltf(None), tri_pos + tri_idx))
put("fuzz_glb", "tri_strip_unindexed", glb(tri_gltf(None, mode=5, indexed=False), tri_pos + tri_idx))

# ---------------------------------------------------------------- images (sky)
def png(w, h, rows):
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    raw = b"".join(b"\0" + r for r in rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def png_empty_idat(w, h, rows):
    """A valid PNG whose first IDAT chunk is empty (legal; stb_image 2.27 mishandled it)."""
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    raw = b"".join(b"\0" + r for r in rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", b"") + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def png_palette(w, h):
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    raw = b"".join(b"\0" + bytes([(x + y) % 2 for x in range(w)]) for y in range(h))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0))
            + chunk(b"PLTE", b"\xff\x00\x00\x00\x00\xff") + chunk(b"tRNS", b"\xff\x80")
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def hdr(w, h):
    px = b"".join(bytes([128, 64, 32, 129]) for _ in range(w * h))
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y %d +X %d\n" % (h, w) + px


def hdr_rle(w, h):
    # New-style RLE scanlines (8 <= width < 32768): 2 2 hi lo, then runs per component.
    out = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w)
    for _ in range(h):
        out += bytes([2, 2, w >> 8, w & 255])
        for c in (100, 50, 25, 130):
            out += bytes([128 + w, c])  # one run of w equal values
    return out


def exr(w, h):
    def attr(name, typ, value):
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value
    chl = b"".join(n + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in (b"B", b"G", b"R")) + b"\0"
    header = (b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
              + attr("channels", "chlist", chl) + attr("compression", "compression", b"\0")
              + attr("dataWindow", "box2i", struct.pack("<4i", 0, 0, w - 1, h - 1))
              + attr("displayWindow", "box2i", struct.pack("<4i", 0, 0, w - 1, h - 1))
              + attr("lineOrder", "lineOrder", b"\0") + attr("pixelAspectRatio", "float", struct.pack("<f", 1))
              + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
              + attr("screenWindowWidth", "float", struct.pack("<f", 1)) + b"\0")
    blocks = []
    for y in range(h):
        data = b"".join(struct.pack("<%df" % w, *([0.25 * (c + 1)] * w)) for c in range(3))
        blocks.append(struct.pack("<ii", y, len(data)) + data)
    offset = len(header) + 8 * h
    table = b""
    for b in blocks:
        table += struct.pack("<Q", offset)
        offset += len(b)
    return header + table + b"".join(blocks)


def exr_tiled(w, h, tx, ty):
    """Single-part tiled (ONE_LEVEL) uncompressed float EXR; R = x + 10 y, G = R + 100, B = R + 200
    (tests/fuzz_regression_test.cpp checks the pixels)."""
    def attr(name, typ, value):
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value
    chl = b"".join(n + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in (b"B", b"G", b"R")) + b"\0"
    header = (b"\x76\x2f\x31\x01" + struct.pack("<I", 2 | 0x200)
              + attr("channels", "chlist", chl) + attr("compression", "compression", b"\0")
              + attr("dataWindow", "box2i", struct.pack("<4i", 0, 0, w - 1, h - 1))
              + attr("displayWindow", "box2i", struct.pack("<4i", 0, 0, w - 1, h - 1))
              + attr("lineOrder", "lineOrder", b"\0") + attr("pixelAspectRatio", "float", struct.pack("<f", 1))
              + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
              + attr("screenWindowWidth", "float", struct.pack("<f", 1))
              + attr("tiles", "tiledesc", struct.pack("<IIB", tx, ty, 0)) + b"\0")
    nx, ny = (w + tx - 1) // tx, (h + ty - 1) // ty
    blocks = []
    for j in range(ny):
        for i in range(nx):
            tw, th = min(tx, w - i * tx), min(ty, h - j * ty)
            data = b""
            for yy in range(th):
                y = j * ty + yy
                for base in (200, 100, 0):  # B, G, R
                    data += struct.pack("<%df" % tw, *[base + (i * tx + xx) + 10 * y for xx in range(tw)])
            blocks.append(struct.pack("<5i", i, j, 0, 0, len(data)) + data)
    offset = len(header) + 8 * len(blocks)
    table = b""
    for b in blocks:
        table += struct.pack("<Q", offset)
        offset += len(b)
    return header + table + b"".join(blocks)

put("fuzz_sky_image", "rgb_2x2.png", png(2, 2, [b"\xff\x00\x00\x00\xff\x00", b"\x00\x00\xff\xff\xff\xff"]))
put("fuzz_sky_image", "palette_4x2.png", png_palette(4, 2))
put("fuzz_sky_image", "empty_idat_2x1.png", png_empty_idat(2, 1, [b"\xff\x00\x00\x00\x00\xff"]))
put("fuzz_sky_image", "flat_3x2.hdr", hdr(3, 2))
put("fuzz_sky_image", "rle_8x2.hdr", hdr_rle(8, 2))
put("fuzz_sky_image", "float_3x2.exr", exr(3, 2))
put("fuzz_sky_image", "tiled_5x3.exr", exr_tiled(5, 3, 2, 2))

# ---------------------------------------------------------------- JSON scene
scene = read(SAMPLES, "scene.json").replace(b'"cube.obj"', b'"m.obj"').replace(b'"cube_le.ply"', b'"m.ply"')
put("fuzz_json_scene", "sample_scene", scene + SPLIT + read(SAMPLES, "cube.obj") + SPLIT + read(SAMPLES, "cube_ascii.ply"))
for n, d in broken("json_", ".json"):
    put("fuzz_json_scene", "broken_" + n, d)
put("fuzz_json_scene", "builtins_only", json.dumps({
    "name": "shapes", "comment": "procedural shapes, every light type, two cameras",
    "materials": {"glass": {"transparency": 0.9, "ior": 1.5, "absorption": [0.1, 0.2, 0.3]},
                  "mirror": {"reflectivity": 1, "specular": 1, "phong_exponent": 200}},
    "meshes": [{"builtin": "plane", "size": [4, 4], "material": "mirror"},
               {"builtin": "box", "size": [1, 2, 1], "material": {"diffuse": 0.5, "emission": [1, 0, 0]},
                "transform": {"rotate": {"axis": [0, 1, 0], "degrees": 30}, "translate": [1, 1, 0]}},
               {"builtin": "sphere", "radius": 0.5, "segments": 8, "material": "glass",
                "transform": {"matrix": [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]}}],
    "lights": [{"type": "point", "position": [0, 4, 0], "intensity": 5, "color": [1, 0.9, 0.8]},
               {"type": "directional", "direction": [0, -1, -1]},
               {"type": "sphere", "position": [2, 3, 1], "radius": 0.2, "samples": 4}],
    "cameras": [{"name": "front", "position": [0, 2, 6], "target": [0, 0, 0], "fov": 40},
                {"name": "top", "position": [0, 8, 0.1], "target": [0, 0, 0], "up": [0, 0, -1]}],
    "sky": {"type": "constant", "color": 0.2, "intensity": 2}, "ambient": [0.05, 0.05, 0.05]}, indent=1))
put("fuzz_json_scene", "sky_image", json.dumps({
    "meshes": [{"builtin": "box"}], "sky": {"type": "image", "image": "sky.hdr"}}).encode()
    + SPLIT + SPLIT + SPLIT + hdr(3, 2))
put("fuzz_json_scene", "ply_and_data", json.dumps({
    "meshes": [{"file": "m.ply", "transform": {"scale": 2}}, {"data": "m.obj"}]}).encode()
    + SPLIT + b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" + SPLIT + read(SAMPLES, "cube_le.ply"))

# ---------------------------------------------------------------- .svo
def svo(depth, codes, seal, origin=(-1.0, -1.0, -1.0), side=2.0):
    """Builds the file of a tree over sorted unique Morton codes (docs/svo-format.md). With
    seal=False the checksum stays 0 and fuzz_svo seals the input itself."""
    codes = sorted(set(codes))
    nodes = []
    if depth > 0:
        leaves_before = 0
        levels = [sorted(set(c >> (3 * (depth - l)) for c in codes)) or [0] for l in range(depth)]
        next_start = 1
        for l in range(depth):
            last = l == depth - 1
            running = 0 if last else next_start
            for p in levels[l]:
                mask = 0
                for c in codes:
                    if c >> (3 * (depth - l)) == p:
                        mask |= 1 << ((c >> (3 * (depth - l - 1))) & 7)
                nodes.append((running, mask))
                running += bin(mask).count("1")
            next_start = running
    attr = struct.pack("<3f3f5fI", 0, 0, 1, 0.5, 0.6, 0.7, 0.1, 0.2, 1.3, -0.1, 0.1, 7)
    body = b"".join(struct.pack("<II", f, m) for f, m in nodes) + attr * len(codes) + attr * len(nodes)
    head = b"SPECSVO\0" + struct.pack("<II3ffII", 1, 80, *origin, side, depth, 48) + struct.pack("<QQQQ", len(nodes), len(codes), 0, 0)
    data = head + b"\0" * 8 + body
    if seal:
        h = 14695981039346656037
        for i, b in enumerate(data):
            if 72 <= i < 80:
                continue
            h = ((h ^ b) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
        data = data[:72] + struct.pack("<Q", h) + data[80:]
    return data


put("fuzz_svo", "depth0_one_voxel.svo", svo(0, [0], False))
put("fuzz_svo", "depth1_two.svo", svo(1, [0, 7], False))
put("fuzz_svo", "depth1_empty.svo", svo(1, [], False))
put("fuzz_svo", "depth2_some.svo", svo(2, [0, 9, 18, 63], False))
put("fuzz_svo", "depth3_diag.svo", svo(3, [i * 73 for i in range(8)], False, origin=(10.0, -3.0, 0.5), side=0.25))
put("fuzz_svo", "depth2_sealed.svo", svo(2, [1, 2, 3, 60], True))
print("fuzz corpus:", {t: len(os.listdir(os.path.join(OUT, t))) for t in sorted(os.listdir(OUT))})

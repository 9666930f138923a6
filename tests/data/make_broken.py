#!/usr/bin/env python3
"""Regenerates tests/data/broken/: one malformed scene file per failure mode. Every file must
make specula::load_scene throw specula::Error naming the file (tests/loaders_test.cpp,
LoadBroken). Run from anywhere: python3 tests/data/make_broken.py"""
import base64, json, os, random, struct

D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "broken")
os.makedirs(D, exist_ok=True)
for f in os.listdir(D):
    os.remove(os.path.join(D, f))

def w(name, data):
    with open(os.path.join(D, name), "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)

rng = random.Random(1234)
garbage = bytes(rng.randrange(256) for _ in range(2048))
tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"

# ---- OBJ
w("obj_empty.obj", "")
w("obj_garbage.obj", garbage)
w("obj_index_out_of_range.obj", tri + "f 1 2 9\n")
w("obj_negative_index.obj", tri + "f -1 -2 -9\n")
w("obj_zero_index.obj", tri + "f 0 1 2\n")
w("obj_normal_out_of_range.obj", tri + "vn 0 0 1\nf 1//1 2//1 3//7\n")
w("obj_mtl_dotdot.obj", "mtllib ../escape.mtl\n" + tri + "f 1 2 3\n")
w("obj_mtl_absolute.obj", "mtllib /etc/passwd\n" + tri + "f 1 2 3\n")
w("obj_inf_vertices.obj", "v 1e999 0 0\nv 1 -1e999 0\nv 0 1 1e999\nf 1 2 3\n")
w("obj_nan_vertices.obj", "v nan 0 0\nv 1 NaN 0\n  v\t0 1 inf\nf 1 2 3\n")
w("obj_polygon_300.obj", "".join(f"v {i} {i*i % 7} 0\n" for i in range(300)) +
  "f " + " ".join(str(i + 1) for i in range(300)) + "\n")
w("obj_no_faces.obj", tri)

# ---- PLY
hdr = lambda fmt, nv, nf, extra="": (f"ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\n"
    f"property float y\nproperty float z\n{extra}element face {nf}\n"
    "property list uchar int vertex_indices\nend_header\n")
verts = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
w("ply_empty.ply", "")
w("ply_bad_magic.ply", "plx\nformat ascii 1.0\nend_header\n")
w("ply_garbage.ply", b"ply\n" + garbage)
w("ply_no_end_header.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n")
w("ply_no_format.ply", "ply\nelement vertex 0\nend_header\n")
w("ply_unknown_type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n0\n")
w("ply_no_xyz.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n")
w("ply_truncated_binary.ply", hdr("binary_little_endian", 3, 1).encode() + verts + b"\x03\x00\x00")
w("ply_truncated_ascii.ply", hdr("ascii", 3, 1) + "0 0 0\n1 0 0\n0 1 0\n3 0 1\n")
w("ply_huge_vertex_count.ply", hdr("binary_little_endian", 4000000000, 1).encode() + verts)
w("ply_huge_face_count.ply", hdr("binary_little_endian", 3, 2**62).encode() + verts + b"\x03" + struct.pack("<3i", 0, 1, 2))
w("ply_count_exceeds_file.ply", hdr("binary_big_endian", 1000, 1).encode() + verts)
w("ply_huge_list_count.ply", ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
  "property float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n").encode()
  + verts + struct.pack("<I", 0xFFFFFFF0) + struct.pack("<3i", 0, 1, 2))
w("ply_skip_list_overrun.ply", ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
  "property float y\nproperty float z\nelement junk 1\nproperty list uchar int stuff\nelement face 1\n"
  "property list uchar int vertex_indices\nend_header\n").encode() + verts + b"\x01\x00\x00\x00")
w("ply_negative_index.ply", hdr("ascii", 3, 1) + "0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n")
w("ply_index_out_of_range.ply", hdr("binary_little_endian", 3, 1).encode() + verts + b"\x03" + struct.pack("<3i", 0, 1, 3))
w("ply_index_out_of_range_be.ply", hdr("binary_big_endian", 3, 1).encode() + struct.pack(">9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
  + b"\x03" + struct.pack(">3i", 0, 1, 70000))
w("ply_bad_number.ply", hdr("ascii", 3, 1) + "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n")
w("ply_negative_count.ply", hdr("ascii", 3, -1) + "0 0 0\n1 0 0\n0 1 0\n")
w("ply_nan_vertices.ply", hdr("ascii", 3, 1) + "nan 0 0\n1 inf 0\n0 1 -nan\n3 0 1 2\n")
w("ply_strip_out_of_range.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
  "property float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n"
  "0 0 0\n1 0 0\n0 1 0\n5 0 1 2 -1 4\n")
w("ply_no_faces.ply", hdr("ascii", 3, 0) + "0 0 0\n1 0 0\n0 1 0\n")

# ---- glTF
def b64(b):
    return "data:application/octet-stream;base64," + base64.b64encode(b).decode()
pos = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
idx = struct.pack("<3H", 0, 1, 2) + b"\0\0"
buf = pos + idx
def gltf(**over):
    g = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
         "nodes": [{"mesh": 0}],
         "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
         "buffers": [{"byteLength": len(buf), "uri": b64(buf)}],
         "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                         {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
         "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0, 0, 0], "max": [1, 1, 0]},
                       {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}]}
    g.update(over)
    return g
def wj(name, g):
    w(name, json.dumps(g, indent=1))
wj("gltf_cyclic_nodes.gltf", gltf(nodes=[{"mesh": 0, "children": [1]}, {"children": [0]}]))
wj("gltf_self_child.gltf", gltf(nodes=[{"mesh": 0, "children": [0]}]))
wj("gltf_cyclic_no_scene.gltf", {k: v for k, v in gltf(nodes=[{"mesh": 0, "children": [1]}, {"children": [0]}]).items() if k not in ("scene", "scenes")})
wj("gltf_child_out_of_range.gltf", gltf(nodes=[{"mesh": 0, "children": [5]}]))
wj("gltf_buffer_dotdot.gltf", gltf(buffers=[{"byteLength": 44, "uri": "../escape.bin"}]))
wj("gltf_buffer_percent_dotdot.gltf", gltf(buffers=[{"byteLength": 44, "uri": "%2e%2e/escape.bin"}]))
wj("gltf_buffer_absolute.gltf", gltf(buffers=[{"byteLength": 44, "uri": "/etc/passwd"}]))
wj("gltf_buffer_scheme.gltf", gltf(buffers=[{"byteLength": 44, "uri": "http://example.com/x.bin"}]))
wj("gltf_image_dotdot.gltf", gltf(images=[{"uri": "../../secret.png"}]))
wj("gltf_buffer_missing.gltf", gltf(buffers=[{"byteLength": 44, "uri": "missing.bin"}]))
wj("gltf_bad_base64.gltf", gltf(buffers=[{"byteLength": 44, "uri": "data:application/octet-stream;base64,@@@@not*base64!!"}]))
wj("gltf_base64_too_short.gltf", gltf(buffers=[{"byteLength": 4000, "uri": b64(buf)}]))
wj("gltf_accessor_out_of_bounds.gltf", gltf(accessors=[{"bufferView": 0, "componentType": 5126, "count": 300, "type": "VEC3"},
                                                  {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}]))
wj("gltf_huge_count.gltf", gltf(accessors=[{"bufferView": 0, "componentType": 5126, "count": 2**62, "type": "VEC3"},
                                          {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}]))
wj("gltf_bufferview_past_buffer.gltf", gltf(bufferViews=[{"buffer": 0, "byteOffset": 40, "byteLength": 36},
                                                       {"buffer": 0, "byteOffset": 36, "byteLength": 6}]))
wj("gltf_bufferview_bad_buffer.gltf", gltf(bufferViews=[{"buffer": 3, "byteOffset": 0, "byteLength": 36},
                                                      {"buffer": 0, "byteOffset": 36, "byteLength": 6}]))
wj("gltf_index_out_of_range.gltf", gltf(buffers=[{"byteLength": len(buf), "uri": b64(pos + struct.pack("<3H", 0, 1, 7) + b"\0\0")}]))
wj("gltf_position_vec2.gltf", gltf(accessors=[{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC2"},
                                             {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}]))
wj("gltf_bad_stride.gltf", gltf(bufferViews=[{"buffer": 0, "byteOffset": 0, "byteLength": 36, "byteStride": 4},
                                           {"buffer": 0, "byteOffset": 36, "byteLength": 6}]))
wj("gltf_material_out_of_range.gltf", gltf(meshes=[{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 4}]}]))
wj("gltf_no_meshes.gltf", {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{}]})
wj("gltf_nan_vertices.gltf", gltf(buffers=[{"byteLength": len(buf), "uri": b64(struct.pack("<9f", float("nan"), 0, 0, 1, 0, 0, 0, 1, 0) + idx)}]))
deep = "[" * 100000 + "]" * 100000  # tinygltf converts extras recursively: stack overflow
w("gltf_deep_nesting.gltf", json.dumps(gltf(extras={"x": 1})).replace('{"x": 1}', deep))
w("gltf_empty.gltf", "")
w("gltf_not_json.gltf", '{"asset": {"version": "2.0"}, "nodes": [ {"mesh": 0,, ]')
w("gltf_garbage.gltf", garbage)

# ---- GLB
def glb(js, bin_=None, total=None, jlen=None, blen=None, deep=None):
    j = json.dumps(js).encode()
    if deep:
        j = j.replace(b'"@DEEP@"', deep.encode())
    j += b" " * (-len(j) % 4)
    out = struct.pack("<II", len(j) if jlen is None else jlen, 0x4E4F534A) + j
    if bin_ is not None:
        b = bin_ + b"\0" * (-len(bin_) % 4)
        out += struct.pack("<II", len(b) if blen is None else blen, 0x004E4942) + b
    n = 12 + len(out)
    return b"glTF" + struct.pack("<II", 2, n if total is None else total) + out
gb = gltf(buffers=[{"byteLength": len(buf)}])
w("glb_empty.glb", b"")
w("glb_short.glb", b"glTF\x02\x00\x00\x00")
w("glb_garbage.glb", b"glTF" + garbage)
w("glb_bad_magic.glb", b"gltf" + glb(gb, buf)[4:])
w("glb_json_chunk_too_long.glb", glb(gb, buf, jlen=100000))
w("glb_bin_chunk_too_long.glb", glb(gb, buf, blen=100000))
w("glb_total_length_wrong.glb", glb(gb, buf, total=99999))
w("glb_truncated.glb", glb(gb, buf)[:-12])
w("glb_version1.glb", b"glTF" + struct.pack("<I", 1) + glb(gb, buf)[8:])
w("glb_missing_bin.glb", glb(gb))
w("glb_buffer_too_long.glb", glb(gltf(buffers=[{"byteLength": 4096}]), buf))
w("glb_deep_nesting.glb", glb(gltf(buffers=[{"byteLength": len(buf)}], extras="@DEEP@"), buf, deep="[" * 20000 + "]" * 20000))
w("glb_cyclic_nodes.glb", glb(gltf(buffers=[{"byteLength": len(buf)}], nodes=[{"mesh": 0, "children": [1]}, {"children": [0]}]), buf))

# ---- JSON scenes
w("json_empty.json", "")
w("json_syntax_error.json", '{\n  "meshes": [\n    {"builtin": "box",}\n  ]\n}\n')
w("json_wrong_type.json", '{"meshes": [{"builtin": "box", "transform": {"scale": "big"}}]}')
w("json_mesh_dotdot.json", '{"meshes": [{"file": "../escape.obj"}]}')
w("json_mesh_absolute.json", '{"meshes": [{"file": "/usr/share/assimp/models/OBJ/box.obj"}]}')
w("json_mesh_missing.json", '{"meshes": [{"file": "missing.ply"}]}')
w("json_unknown_material.json", '{"meshes": [{"builtin": "sphere", "material": "nope"}]}')
w("json_unknown_shape.json", '{"meshes": [{"builtin": "teacup"}]}')
w("json_bad_light.json", '{"lights": [{"type": "sphere", "radius": 0}]}')
w("json_bad_camera.json", '{"cameras": [{"position": [0, 0, 0], "target": [0, 0, 0]}]}')
w("json_not_object.json", '[1, 2, 3]')
w("json_nan.json", '{"meshes": [{"builtin": "box", "transform": {"translate": [NaN, 0, 0]}}]}')
w("json_broken_mesh_inside.json", '{"meshes": [{"file": "ply_truncated_binary.ply"}]}')
print(len(os.listdir(D)), "files in", D)

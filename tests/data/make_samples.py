#!/usr/bin/env python3
"""Regenerates tests/data/samples/: small valid files of every format (a unit cube with two
materials), used as seeds by the loader mutation test (tests/loader_corpus_test.cpp, LoadFuzz)."""
import base64, json, os, struct

D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "samples")
os.makedirs(D, exist_ok=True)
V = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
Q = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
T = [t for a, b, c, d in Q for t in ((a, b, c), (a, c, d))]

def w(name, data):
    with open(os.path.join(D, name), "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)

w("cube.mtl", "newmtl red\nKd 1 0 0\nKs 0.5 0.5 0.5\nNs 50\nillum 3\nnewmtl glass\nKd 0 0 0\nNi 1.5\nd 0.2\nTf 0.9 0.8 0.7\nillum 4\n")
obj = "mtllib cube.mtl\n" + "".join("v %d %d %d\n" % v for v in V) + "vn 0 0 1\nvt 0 0\n"
obj += "o cube\nusemtl red\n" + "".join("f %d/1/1 %d/1/1 %d/1/1 %d/1/1\n" % tuple(i + 1 for i in q) for q in Q[:3])
obj += "g other\nusemtl glass\n" + "".join("f %d %d %d %d\n" % tuple(i + 1 for i in q) for q in Q[3:])
w("cube.obj", obj)

def ply_header(fmt):
    return ("ply\nformat %s 1.0\ncomment sample\nelement vertex 8\nproperty float x\nproperty float y\n"
            "property double z\nproperty uchar red\nelement junk 2\nproperty list uchar short stuff\nproperty int n\n"
            "element face 6\nproperty list uchar int vertex_indices\n"
            "element tristrips 1\nproperty list int int vertex_indices\nend_header\n" % fmt)
strip = [0, 1, 2, 3, -1, 4, 5, 6, 7]
w("cube_ascii.ply", ply_header("ascii") + "".join("%d %d %d 255\n" % v for v in V)
  + "2 7 -8 1\n0 5\n" + "".join("4 %d %d %d %d\n" % q for q in Q) + "%d %s\n" % (len(strip), " ".join(map(str, strip))))
for name, e in (("cube_le.ply", "<"), ("cube_be.ply", ">")):
    b = ply_header("binary_little_endian" if e == "<" else "binary_big_endian").encode()
    for v in V:
        b += struct.pack(e + "ffdB", v[0], v[1], v[2], 255)
    b += struct.pack(e + "B2hi", 2, 7, -8, 1) + struct.pack(e + "Bi", 0, 5)
    for q in Q:
        b += struct.pack(e + "B4i", 4, *q)
    b += struct.pack(e + "i", len(strip)) + struct.pack(e + "%di" % len(strip), *strip)
    w(name, b)

pos = b"".join(struct.pack("<3f", *v) for v in V)
nrm = b"".join(struct.pack("<3f", 0, 0, 1) for v in V)
idx = b"".join(struct.pack("<3H", *t) for t in T)
buf = pos + nrm + idx
def gltf(uri):
    g = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 2]}],
         "nodes": [{"children": [1], "translation": [0, 1, 0]},
                   {"mesh": 0, "rotation": [0, 0.3826834, 0, 0.9238795], "scale": [1, 2, 1]},
                   {"camera": 0, "translation": [0, 1, 6], "extensions": {"KHR_lights_punctual": {"light": 0}}}],
         "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0},
                                    {"attributes": {"POSITION": 0}, "indices": 2, "mode": 5}]}],
         "materials": [{"name": "glass", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0, "roughnessFactor": 0.1},
                        "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_ior": {"ior": 1.5},
                                       "KHR_materials_volume": {"attenuationColor": [0.9, 0.5, 0.5], "attenuationDistance": 1}}}],
         "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}],
         "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 10}]}},
         "buffers": [{"byteLength": len(buf)}],
         "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 96, "byteStride": 12},
                         {"buffer": 0, "byteOffset": 96, "byteLength": 96},
                         {"buffer": 0, "byteOffset": 192, "byteLength": len(idx)}],
         "accessors": [{"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]},
                       {"bufferView": 1, "componentType": 5126, "count": 8, "type": "VEC3"},
                       {"bufferView": 2, "componentType": 5123, "count": len(T) * 3, "type": "SCALAR"}]}
    if uri:
        g["buffers"][0]["uri"] = uri
    return g
w("cube_embedded.gltf", json.dumps(gltf("data:application/octet-stream;base64," + base64.b64encode(buf).decode()), indent=1))
w("cube_external.bin", buf)
w("cube_external.gltf", json.dumps(gltf("cube_external.bin"), indent=1))
j = json.dumps(gltf(None)).encode()
j += b" " * (-len(j) % 4)
b = buf + b"\0" * (-len(buf) % 4)
body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(b), 0x004E4942) + b
w("cube.glb", b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
w("scene.json", json.dumps({
    "materials": {"m": {"diffuse": [0.5, 0.5, 0.5], "reflectivity": 0.5}},
    "meshes": [{"file": "cube.obj"}, {"file": "cube_le.ply", "material": "m", "transform": {"translate": [2, 0, 0]}},
               {"builtin": "sphere", "radius": 0.5, "segments": 6, "transform": {"scale": [1, 2, 1]}}],
    "lights": [{"type": "point", "position": [0, 4, 0], "intensity": 5}],
    "cameras": [{"position": [0, 2, 6], "target": [0, 0, 0]}],
    "sky": {"type": "gradient"}}, indent=1))
print(sorted(os.listdir(D)))

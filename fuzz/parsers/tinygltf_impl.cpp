// See stb_impl.cpp: tinygltf, instrumented for fuzzing (stb_image comes from stb_impl.cpp).
#pragma clang diagnostic ignored "-Weverything"
#define TINYGLTF_IMPLEMENTATION
#include <tiny_gltf.h>

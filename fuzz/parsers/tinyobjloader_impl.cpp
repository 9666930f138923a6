// See stb_impl.cpp: tinyobjloader, instrumented for fuzzing.
#pragma clang diagnostic ignored "-Weverything"
#define TINYOBJLOADER_IMPLEMENTATION
#include <tiny_obj_loader.h>

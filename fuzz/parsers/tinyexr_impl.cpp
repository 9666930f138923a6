// See stb_impl.cpp: tinyexr, instrumented for fuzzing (zlib from the system, as Debian's build).
#pragma clang diagnostic ignored "-Weverything"
#define TINYEXR_IMPLEMENTATION
#define TINYEXR_USE_MINIZ 0
#include <zlib.h>
#include <tinyexr.h>

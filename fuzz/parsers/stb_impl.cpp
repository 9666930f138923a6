// The fuzz build compiles the third-party parsers from Debian's headers so they are
// instrumented too (coverage feedback, ASan/UBSan inside them); the normal build links Debian's
// prebuilt libstb / libtinyobjloader / libtinygltf / libtinyexr instead.
#pragma clang diagnostic ignored "-Weverything"
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb_image.h>
#include <stb_image_write.h>

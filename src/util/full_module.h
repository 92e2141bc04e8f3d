// The full module: every command of the CLI and OpenCV's image and video codecs, in one shared
// library beside the `rolamos` launcher (librolamos_full.so). The launcher itself is linked
// without OpenImageIO, GDAL and OpenCV's imgcodecs and videoio: they bring ~280 shared libraries
// whose loading took 0.18 s of every command's start (bench/RESULTS.md, session 37), and a
// mosaic of JPEG frames needs none of them. What does need them loads this module, once.
#pragma once

#include <string>

namespace rolamos {

// Where the module is looked for: beside the running program, then in ../lib/rolamos.
std::string FullModulePath();

// The address of an `extern "C"` symbol of the module, loaded on first use (thread-safe).
// Throws Error naming the module's path and the loader's message when it cannot be loaded or
// lacks the symbol.
void* FullModuleSymbol(const char* name);

}  // namespace rolamos

#pragma once
// mesoscan's own loadable modules: code that needs a library with a large dependency tree
// (OpenImageIO: 262 shared libraries, whose symbol resolution alone cost every process 0.18
// CPU-s at start) lives in a shared module, libmesoscan_<name>.so, loaded the first time it is
// used, so commands that never need it (the reconstruct path: frames through the PNG fast path,
// EXRs through OpenEXR) never load that tree.
//
// The module is looked for, in order: in $MESOSCAN_MODULE_DIR if set, beside the running
// executable, in <executable's folder>/../lib/mesoscan (an installed layout), and in the build
// tree's module folder (so tests and tools built anywhere in the tree find it). It must export
// `extern "C" const void* mesoscan_module_<name>()`, returning its interface object.

#include <string>

namespace mesoscan {

// The interface object of module `name`, loaded (once, thread-safe) on the first call. Throws
// Error(kInternal) naming the module, the folders searched and the loader's message if it
// cannot be loaded.
const void* LoadModule(const std::string& name);

// Where module `name` was loaded from ("" if it is not loaded yet).
std::string LoadedModulePath(const std::string& name);

}  // namespace mesoscan

// How the owner of a module reaches it: MESOSCAN_DECLARE_MODULE(name); at file scope, then
// MESOSCAN_MODULE(name) for its interface object. Sanitizer and fuzz builds link the module's
// code into its owner (MESOSCAN_LINKED_MODULES, see mesoscan_add_module in CMakeLists.txt) and
// call its entry directly; every other build loads it with LoadModule.
#define MESOSCAN_DECLARE_MODULE(name) extern "C" const void* mesoscan_module_##name()
#ifdef MESOSCAN_LINKED_MODULES
#define MESOSCAN_MODULE(name) (mesoscan_module_##name())
#else
#define MESOSCAN_MODULE(name) (::mesoscan::LoadModule(#name))
#endif

#pragma once
// MESOSCAN_IGNORE_LIBRARY_LEAKS(): inside a scope, LeakSanitizer ignores what is allocated there.
// For tests that drive a library which keeps or leaks memory of its own (not ours): OpenImageIO
// 2.4's per-thread error strings of refused inputs, libgphoto2's libusb device lists. A no-op
// without AddressSanitizer.
#ifdef __SANITIZE_ADDRESS__
#include <sanitizer/lsan_interface.h>
#define MESOSCAN_IGNORE_LIBRARY_LEAKS() __lsan::ScopedDisabler lsan_disabler
#else
#define MESOSCAN_IGNORE_LIBRARY_LEAKS() \
  do {                                  \
  } while (0)
#endif

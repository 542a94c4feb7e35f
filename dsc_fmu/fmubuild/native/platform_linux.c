/* Where Linux keeps a CPython (see platform.h): the dynamic loader's search, and an installation's lib/
   or its Debian-style multiarch folder for the CPU this binary runs on. */

#include "platform.h"

#include <stdio.h>

/* The name of the system's CPython library (the minor version for %d). */
#ifndef DSC_SYSTEM_PYTHON
#define DSC_SYSTEM_PYTHON "libpython3.%d.so.1.0"
#endif

#if defined(__x86_64__)
#define MULTIARCH "x86_64-linux-gnu"
#elif defined(__aarch64__)
#define MULTIARCH "aarch64-linux-gnu"
#else
#error the multiarch folder of this CPU is not known
#endif

const char PLATFORM_OS[] = "linux";

void platform_registered_pythons(void (*visit)(void *, const char *, const char *, const char *, int), void *context,
                                 int oldest) {
    char name[64];
    for (int minor = NEWEST_MINOR; minor >= oldest; minor--) {
        snprintf(name, sizeof name, DSC_SYSTEM_PYTHON, minor);
        visit(context, name, NULL, "", minor);
    }
}

static const char *const LIBRARY_PLACES[] = {"lib/", "lib/" MULTIARCH "/"};
const char PLATFORM_LIBRARY_PLACES[] = "lib/" DSC_SYSTEM_PYTHON " or lib/" MULTIARCH "/" DSC_SYSTEM_PYTHON;

int platform_library_in(const char *folder, int place, int minor, char *path, size_t size) {
    if (place < 0 || place >= (int)(sizeof LIBRARY_PLACES / sizeof LIBRARY_PLACES[0])) return -1;
    char name[64];
    snprintf(name, sizeof name, DSC_SYSTEM_PYTHON, minor);
    snprintf(path, size, "%s/%s%s", folder, LIBRARY_PLACES[place], name);
    return 0;
}

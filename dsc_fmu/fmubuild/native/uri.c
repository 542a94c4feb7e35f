/* Resource locations (uri.h). */

#include "uri.h"

#include "platform.h"

#include <string.h>

static int hex(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int uri_to_path(const char *uri, char *path, size_t size) {
    if (!uri || !*uri) return -1;
    const char *p = uri;
    int encoded = strncmp(p, "file:", 5) == 0;
    if (encoded) {
        p += 5;
        if (strncmp(p, "//localhost/", 12) == 0) p += 11;
        else if (strncmp(p, "///", 3) == 0) p += 2;
    }
    size_t k = 0;
    for (; *p && k + 1 < size; p++) {
        if (encoded && *p == '%' && hex(p[1]) >= 0 && hex(p[2]) >= 0) {
            path[k++] = (char)(hex(p[1]) * 16 + hex(p[2]));
            p += 2;
        } else {
            path[k++] = *p;
        }
    }
    path[k] = '\0';
    if (*p) return -1;
    platform_native_path(path);
    return platform_is_absolute(path) ? 0 : -1;
}

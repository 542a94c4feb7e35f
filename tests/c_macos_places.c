/* The macOS platform seam's places (platform_macos.c), compiled for Linux with DSC_PLACES_ROOT naming a
   folder laid out as a Mac: prints what the seam answers, one line each.
     c_macos_places registered OLDEST        "<minor> <label>|<library>" per CPython the seam visits
     c_macos_places in FOLDER MINOR          "<place> <path>" per place of an installation folder
     c_macos_places home LIBRARY MINOR       the home found above LIBRARY, or "-1 <why>" */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "platform.h"

static void print(void *context, const char *library, const char *home, const char *label, int minor) {
    printf("%d %s|%s\n", minor, label, library);
}

int main(int argc, char **argv) {
    if (argc == 3 && strcmp(argv[1], "registered") == 0) {
        platform_registered_pythons(print, NULL, atoi(argv[2]));
        return 0;
    }
    if (argc == 4 && strcmp(argv[1], "in") == 0) {
        char path[PLATFORM_PATH_MAX];
        for (int place = 0; platform_library_in(argv[2], place, atoi(argv[3]), path, sizeof path) == 0; place++) {
            printf("%d %s\n", place, path);
        }
        return 0;
    }
    if (argc == 4 && strcmp(argv[1], "home") == 0) {
        char home[PLATFORM_PATH_MAX], why[512] = "";
        int layout = platform_python_home(argv[2], "", atoi(argv[3]), home, sizeof home, why, sizeof why);
        printf("%d %s\n", layout, layout < 0 ? why : home);
        return 0;
    }
    fprintf(stderr, "usage: c_macos_places registered OLDEST | in FOLDER MINOR | home LIBRARY MINOR\n");
    return 2;
}

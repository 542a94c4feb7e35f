/* Which shared libraries the dynamic loader can load: for each argument (a name the loader searches
   for, or a path), dlopen it and print "loaded ARG" or "refused ARG: <dlerror>". Libraries loaded stay
   loaded (RTLD_LOCAL, so their symbols do not meet). Exits 0 once every argument was tried.

   usage: c_dlopen LIBRARY [LIBRARY ...] */

#include <dlfcn.h>
#include <stdio.h>

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: c_dlopen LIBRARY [LIBRARY ...]\n");
        return 1;
    }
    for (int i = 1; i < argc; i++) {
        if (dlopen(argv[i], RTLD_LAZY | RTLD_LOCAL)) {
            printf("loaded %s\n", argv[i]);
        } else {
            const char *error = dlerror();
            printf("refused %s: %s\n", argv[i], error ? error : "no message");
        }
    }
    return 0;
}

/* Where a Mac keeps a CPython (see platform.h): the installers' own places (python.org, Homebrew on Apple
   Silicon and Intel, conda's active environment, pyenv, Xcode and its Command Line Tools), then the
   dynamic loader's search; an installation's lib/ or its framework version folder. */

#define _POSIX_C_SOURCE 200809L /* scandir */
#include "platform.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The name of the system's CPython library (the minor version for %d). */
#ifndef DSC_SYSTEM_PYTHON
#define DSC_SYSTEM_PYTHON "libpython3.%d.dylib"
#endif
/* The folder the places below are absolute in: "" on a Mac; a folder laid out as one where the
   places are tested on another system. */
#ifndef DSC_PLACES_ROOT
#define DSC_PLACES_ROOT ""
#endif

typedef void (*Visit)(void *context, const char *library, const char *home, const char *label, int minor);

const char PLATFORM_OS[] = "darwin";

/* The installers' places of CPython 3.X's library (the minor version for each %d), in the order tried. */
static const struct {
    const char *pattern;
    const char *label;
} INSTALLS[] = {
    {"/Library/Frameworks/Python.framework/Versions/3.%d/Python", "python.org's"},
    {"/opt/homebrew/opt/python@3.%d/Frameworks/Python.framework/Versions/3.%d/Python", "Homebrew's"},
    {"/usr/local/opt/python@3.%d/Frameworks/Python.framework/Versions/3.%d/Python", "Homebrew's"},
};
static const struct {
    const char *pattern;
    const char *label;
} DEVELOPER_TOOLS[] = {
    {"/Applications/Xcode.app/Contents/Developer/Library/Frameworks/Python3.framework/Versions/3.%d/Python3", "Xcode's"},
    {"/Library/Developer/CommandLineTools/Library/Frameworks/Python3.framework/Versions/3.%d/Python3",
     "the Command Line Tools'"},
};

static void visit_if_file(Visit visit, void *context, const char *library, const char *label, int minor) {
    if (platform_is_file(library)) visit(context, library, NULL, label, minor);
}

static void visit_fixed(Visit visit, void *context, const char *pattern, const char *label, int minor) {
    static char library[PLATFORM_PATH_MAX];
    snprintf(library, sizeof library, "%s", DSC_PLACES_ROOT);
    size_t used = strlen(library);
    snprintf(library + used, sizeof library - used, pattern, minor, minor);
    visit_if_file(visit, context, library, label, minor);
}

/* conda's active environment: $CONDA_PREFIX/lib. */
static void visit_conda(Visit visit, void *context, int minor) {
    static char prefix[PLATFORM_PATH_MAX], library[PLATFORM_PATH_MAX + 64];
    if (!platform_getenv("CONDA_PREFIX", prefix, sizeof prefix)) return;
    snprintf(library, sizeof library, "%s/lib/" DSC_SYSTEM_PYTHON, prefix, minor);
    visit_if_file(visit, context, library, "conda's (CONDA_PREFIX)", minor);
}

/* The order of pyenv's version folders, newest first: "3.12.10" before "3.12.9" before "3.12.9t", by the
   numbers in their names, then by name. */
static int newest_first(const struct dirent **a, const struct dirent **b) {
    const char *p = (*a)->d_name, *q = (*b)->d_name;
    while (*p && *q) {
        char *p_end, *q_end;
        long x = strtol(p, &p_end, 10), y = strtol(q, &q_end, 10);
        if (p_end == p || q_end == q) break;
        if (x != y) return x > y ? -1 : 1;
        p = p_end + (*p_end == '.');
        q = q_end + (*q_end == '.');
    }
    return strcmp((*b)->d_name, (*a)->d_name);
}

/* pyenv's versions ($PYENV_ROOT, else ~/.pyenv), newest first; a version has a library only if built with
   --enable-shared or --enable-framework. */
static void visit_pyenv(Visit visit, void *context, int minor) {
    static char root[PLATFORM_PATH_MAX], versions[PLATFORM_PATH_MAX + 16], library[2 * PLATFORM_PATH_MAX];
    if (!platform_getenv("PYENV_ROOT", root, sizeof root)) {
        static char home[PLATFORM_PATH_MAX];
        if (!platform_getenv("HOME", home, sizeof home)) return;
        snprintf(root, sizeof root, "%s/.pyenv", home);
    }
    snprintf(versions, sizeof versions, "%s/versions", root);
    struct dirent **names;
    int count = scandir(versions, &names, NULL, newest_first);
    if (count < 0) return;
    for (int i = 0; i < count; i++) {
        if (names[i]->d_name[0] != '.') {
            snprintf(library, sizeof library, "%s/%s/lib/" DSC_SYSTEM_PYTHON, versions, names[i]->d_name, minor);
            visit_if_file(visit, context, library, "pyenv's", minor);
        }
        free(names[i]);
    }
    free(names);
}

void platform_registered_pythons(Visit visit, void *context, int oldest) {
    char name[64];
    for (int minor = NEWEST_MINOR; minor >= oldest; minor--) {
        for (size_t i = 0; i < sizeof INSTALLS / sizeof INSTALLS[0]; i++) {
            visit_fixed(visit, context, INSTALLS[i].pattern, INSTALLS[i].label, minor);
        }
        visit_conda(visit, context, minor);
        visit_pyenv(visit, context, minor);
        for (size_t i = 0; i < sizeof DEVELOPER_TOOLS / sizeof DEVELOPER_TOOLS[0]; i++) {
            visit_fixed(visit, context, DEVELOPER_TOOLS[i].pattern, DEVELOPER_TOOLS[i].label, minor);
        }
    }
    for (int minor = NEWEST_MINOR; minor >= oldest; minor--) {
        snprintf(name, sizeof name, DSC_SYSTEM_PYTHON, minor);
        visit(context, name, NULL, "", minor);
    }
}

const char PLATFORM_LIBRARY_PLACES[] = "lib/" DSC_SYSTEM_PYTHON ", a framework's Versions/3.%d/Python or Python3, or "
                                       "Frameworks/Python.framework/Versions/3.%d/Python (Homebrew's prefix)";

/* Whether `folder`'s last name is "3.`minor`" (a framework's version folder). */
static int is_version_folder(const char *folder, int minor) {
    char name[16];
    const char *slash = strrchr(folder, '/');
    snprintf(name, sizeof name, "3.%d", minor);
    return strcmp(slash ? slash + 1 : folder, name) == 0;
}

int platform_library_in(const char *folder, int place, int minor, char *path, size_t size) {
    switch (place) {
    case 0:
        snprintf(path, size, "%s/lib/" DSC_SYSTEM_PYTHON, folder, minor);
        return 0;
    case 1:
    case 2: /* a framework's version folder holds its library as Python (Python3: Apple's) */
        if (is_version_folder(folder, minor)) {
            snprintf(path, size, "%s/%s", folder, place == 1 ? "Python" : "Python3");
        } else {
            snprintf(path, size, "%s", "");
        }
        return 0;
    case 3:
        snprintf(path, size, "%s/Frameworks/Python.framework/Versions/3.%d/Python", folder, minor);
        return 0;
    default:
        return -1;
    }
}

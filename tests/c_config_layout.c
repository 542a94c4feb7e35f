/* Compiles only where the PyConfig and PyPreConfig offsets that pyhost.c keeps for CPython 3.MINOR are those of
   that version's own header (Include/cpython/initconfig.h), for the target it is compiled for.

   usage: zig cc -target TARGET -fsyntax-only -I<include/python3.X> -DPARSE_ARGV=.. -DSITE_IMPORT=..
          -DWRITE_BYTECODE=.. -DUSER_SITE_DIRECTORY=.. -DCONFIG_C_STDIO=.. -DHOME=.. -DUTF8_MODE=..
          c_config_layout.c
   The header is read alone: what it needs from Python.h is declared here, and MS_WINDOWS is defined where
   CPython's own Windows build defines it. */

#include <stddef.h>
#include <stdint.h>
#include <wchar.h>

typedef intptr_t Py_ssize_t;
typedef struct _object PyObject;
#define PyAPI_FUNC(type) type
#define PyAPI_DATA(type) extern type
#define Py_DEPRECATED(version)
#ifdef _WIN32
#define MS_WINDOWS
#endif
#define Py_CPYTHON_INITCONFIG_H
#include "cpython/initconfig.h"

_Static_assert(offsetof(PyConfig, isolated) == sizeof(int), "isolated");
_Static_assert(offsetof(PyConfig, use_environment) == 2 * sizeof(int), "use_environment");
_Static_assert(offsetof(PyConfig, parse_argv) == PARSE_ARGV, "parse_argv");
_Static_assert(offsetof(PyConfig, site_import) == SITE_IMPORT, "site_import");
_Static_assert(offsetof(PyConfig, write_bytecode) == WRITE_BYTECODE, "write_bytecode");
_Static_assert(offsetof(PyConfig, user_site_directory) == USER_SITE_DIRECTORY, "user_site_directory");
_Static_assert(offsetof(PyConfig, configure_c_stdio) == CONFIG_C_STDIO, "configure_c_stdio");
_Static_assert(offsetof(PyConfig, home) == HOME, "home");
_Static_assert(offsetof(PyPreConfig, utf8_mode) == UTF8_MODE * sizeof(int), "utf8_mode");

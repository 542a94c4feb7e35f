/* Resource locations: what an importer passes as the FMU's resources, made a native path. */

#ifndef DSC_URI_H
#define DSC_URI_H

#include <stddef.h>

/* The native path of a file URI (file:///C:/x, file:/x, file://localhost/x, file://server/share/x
   for a share, percent-escapes decoded) or of an absolute path, in `path`; 0, or -1 if it is neither. */
int uri_to_path(const char *uri, char *path, size_t size);

#endif

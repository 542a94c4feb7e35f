/* What the project's C importers share: loggers that print to stderr, and a status check that exits. */

#ifndef DSC_TESTS_FMI_HOST_H
#define DSC_TESTS_FMI_HOST_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"

static void logger2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s %d] ", instance, status);
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    fprintf(stderr, "[%d] %s\n", status, message);
}

/* Exit with a message if `status` is worse than a warning. */
static void check(int status, const char *call) {
    if (status > 1) {
        fprintf(stderr, "%s failed with status %d\n", call, status);
        exit(1);
    }
}

#endif

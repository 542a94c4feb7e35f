/* The slave's message queue (slave.h): messages that arise while the GIL is held are queued here and
   handed to the importer's logger once it is released, in order, on the calling thread. */

#include "slave_calls.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const STATUS_CATEGORIES[] = {DSC_STATUS_CATEGORIES};
_Static_assert(sizeof STATUS_CATEGORIES / sizeof STATUS_CATEGORIES[0] == STATUS_FATAL + 1,
               "DSC_STATUS_CATEGORIES names the category of every status, OK to fatal");

const char *slave_category(int status) {
    return STATUS_CATEGORIES[status >= STATUS_OK && status <= STATUS_FATAL ? status : STATUS_FATAL];
}

void queue_message(Slave *s, int status, const char *category, const char *text) {
    size_t length = strlen(text);
    Message *message = malloc(sizeof *message + length + 1);
    if (!message) return;
    message->next = NULL;
    message->status = status;
    snprintf(message->category, sizeof message->category, "%s", category);
    memcpy(message->text, text, length + 1);
    *s->last = message;
    s->last = &message->next;
}

void slave_deliver(Slave *s) {
    Message *message = s->messages;
    s->messages = NULL;
    s->last = &s->messages;
    while (message) {
        Message *next = message->next;
        s->log(s->context, message->status, message->category, message->text);
        free(message);
        message = next;
    }
}

void slave_vlog(Slave *s, int status, const char *call, const char *format, va_list args) {
    char message[2048];
    int k = call ? snprintf(message, sizeof message, "%s: %s: ", s->instance_name, call)
                 : snprintf(message, sizeof message, "%s: ", s->instance_name);
    vsnprintf(message + k, sizeof message - k, format, args);
    queue_message(s, status, slave_category(status), message);
}

void say(Slave *s, int status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    slave_vlog(s, status, NULL, format, args);
    va_end(args);
}

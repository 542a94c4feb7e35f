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

/* A message of `status` and `category` with room for a text of `length` characters, not yet queued; NULL
   (counted as lost) if there is no memory for it. */
static Message *new_message(Slave *s, int status, const char *category, size_t length) {
    size_t category_size = strlen(category) + 1;
    Message *message = malloc(sizeof *message + length + 1 + category_size);
    if (!message) {
        s->lost++;
        return NULL;
    }
    message->next = NULL;
    message->status = status;
    message->category = memcpy(message->text + length + 1, category, category_size);
    return message;
}

static void append(Slave *s, Message *message) {
    *s->last = message;
    s->last = &message->next;
}

void queue_message(Slave *s, int status, const char *category, const char *text) {
    size_t length = strlen(text);
    Message *message = new_message(s, status, category, length);
    if (!message) return;
    memcpy(message->text, text, length + 1);
    append(s, message);
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
    if (s->lost) {
        char text[160];
        snprintf(text, sizeof text, "%s: %d messages were lost: no memory to queue them", s->instance_name, s->lost);
        s->lost = 0;
        s->log(s->context, STATUS_WARNING, slave_category(STATUS_WARNING), text);
    }
}

/* Formatted in place, at its full length: measured first, then written into the message's own block. */
void slave_vlog(Slave *s, int status, const char *call, const char *format, va_list args) {
    va_list again;
    va_copy(again, args);
    const char *separator = call ? ": " : "";
    call = call ? call : "";
    int prefix = snprintf(NULL, 0, "%s: %s%s", s->instance_name, call, separator);
    int body = vsnprintf(NULL, 0, format, args);
    Message *message = prefix < 0 || body < 0 ? NULL
                       : new_message(s, status, slave_category(status), (size_t)prefix + (size_t)body);
    if (message) {
        snprintf(message->text, (size_t)prefix + 1, "%s: %s%s", s->instance_name, call, separator);
        vsnprintf(message->text + prefix, (size_t)body + 1, format, again);
        append(s, message);
    }
    va_end(again);
}

void say(Slave *s, int status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    slave_vlog(s, status, NULL, format, args);
    va_end(args);
}

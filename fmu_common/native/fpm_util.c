/* fpm_util.c - helpers shared by the FMI layers: logging, the variable table, FMU states. */
#include "fpm.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

void fpm_log(const fpm_logger *lg, int status, const char *fmt, ...)
{
    char msg[FPM_MSG_MAX];
    const char *cat;
    size_t i;
    va_list ap;
    if (lg == NULL || lg->emit == NULL) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    /* hosts may pass the message to printf as a format: no '%' goes out */
    for (i = 0; msg[i] != '\0'; i++)
        if (msg[i] == '%') msg[i] = '#';
    switch (status) {
    case FPM_OK: cat = "logAll"; break;
    case FPM_WARNING: cat = "logStatusWarning"; break;
    case FPM_DISCARD: cat = "logStatusDiscard"; break;
    case FPM_ERROR: cat = "logStatusError"; break;
    default: cat = "logStatusFatal"; break;
    }
    lg->emit(lg->env, status, cat, msg);
}

void fpm_start_values(fpm_values *v)
{
    int i;
    for (i = 0; i < FPM_MAX_VARS; i++) {
        const fpm_var *var = &fpm_vars[i];
        if (var->name == NULL || var->causality == FPM_OUTPUT) continue;
        if (var->type == FPM_STRING) strcpy(v->string[i], var->start_string);
        else v->real[i] = var->start_real;
    }
}

int fpm_lookup(unsigned vr)
{
    if (vr >= FPM_MAX_VARS || fpm_vars[vr].name == NULL) return -1;
    return (int)vr;
}

unsigned long long fpm_hash(const void *data, size_t n, unsigned long long h)
{
    const unsigned char *p = (const unsigned char *)data;
    size_t i;
    for (i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

/* Serialised FMU state: "FPMS", format version, payload size, hash of the model's identity
 * (name, token, payload size), the payload, then the FNV-1a hash of everything before it. */
#define MAGIC "FPMS"
#define FORMAT 1u
#define HEADER 24u

static unsigned long long identity(size_t size)
{
    unsigned long long h = 14695981039346656037ULL;
    unsigned long long s = (unsigned long long)size;
    h = fpm_hash(fpm_model_name, strlen(fpm_model_name), h);
    h = fpm_hash(fpm_token, strlen(fpm_token), h);
    return fpm_hash(&s, sizeof s, h);
}

size_t fpm_serialized_size(size_t size) { return HEADER + size + 8u; }

static void put_u32(unsigned char *p, unsigned v)
{
    int i;
    for (i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}

static void put_u64(unsigned char *p, unsigned long long v)
{
    int i;
    for (i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}

static unsigned get_u32(const unsigned char *p)
{
    unsigned v = 0;
    int i;
    for (i = 0; i < 4; i++) v |= (unsigned)p[i] << (8 * i);
    return v;
}

static unsigned long long get_u64(const unsigned char *p)
{
    unsigned long long v = 0;
    int i;
    for (i = 0; i < 8; i++) v |= (unsigned long long)p[i] << (8 * i);
    return v;
}

void fpm_serialize(const void *mode_and_model, size_t size, unsigned char *out)
{
    memcpy(out, MAGIC, 4);
    put_u32(out + 4, FORMAT);
    put_u64(out + 8, (unsigned long long)size);
    put_u64(out + 16, identity(size));
    memcpy(out + HEADER, mode_and_model, size);
    put_u64(out + HEADER + size, fpm_hash(out, HEADER + size, 14695981039346656037ULL));
}

int fpm_deserialize(const unsigned char *in, size_t n, void *mode_and_model, size_t size,
                    char *why)
{
    if (in == NULL || n < HEADER + 8u || memcmp(in, MAGIC, 4) != 0) {
        snprintf(why, FPM_MSG_MAX, "not a serialised FMU state of %s (%lu bytes, no header)",
                 fpm_model_name, (unsigned long)n);
        return FPM_ERROR;
    }
    if (get_u32(in + 4) != FORMAT) {
        snprintf(why, FPM_MSG_MAX, "serialised FMU state of format version %u; this FMU reads %u",
                 get_u32(in + 4), FORMAT);
        return FPM_ERROR;
    }
    if (get_u64(in + 8) != (unsigned long long)size || n != fpm_serialized_size(size)) {
        snprintf(why, FPM_MSG_MAX, "serialised FMU state of %lu bytes; a state of this FMU has %lu",
                 (unsigned long)n, (unsigned long)fpm_serialized_size(size));
        return FPM_ERROR;
    }
    if (get_u64(in + 16) != identity(size)) {
        snprintf(why, FPM_MSG_MAX, "the serialised FMU state belongs to another model or build "
                 "(this is %s, token %s)", fpm_model_name, fpm_token);
        return FPM_ERROR;
    }
    if (get_u64(in + HEADER + size) != fpm_hash(in, HEADER + size, 14695981039346656037ULL)) {
        snprintf(why, FPM_MSG_MAX, "the serialised FMU state is corrupt (its checksum does not "
                 "match its bytes)");
        return FPM_ERROR;
    }
    memcpy(mode_and_model, in + HEADER, size);
    return FPM_OK;
}

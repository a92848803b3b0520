#include "jsonmini.h"
#include <stdlib.h>
#include <string.h>
#include <ctype.h>

static char *p;

static void ws(void) { while (*p && isspace((unsigned char)*p)) p++; }

static char *parse_str(void)
{
    if (*p != '"') return NULL;
    char *s = ++p, *o = p;
    while (*p && *p != '"') {
        if (*p == '\\' && p[1]) { p++; }
        *o++ = *p++;
    }
    if (*p != '"') return NULL;
    p++;
    *o = 0;
    return s;
}

static jnode_t *parse_val(void)
{
    ws();
    jnode_t *n = calloc(1, sizeof *n);
    if (!n) return NULL;
    if (*p == '{' || *p == '[') {
        char close = *p == '{' ? '}' : ']';
        n->type = *p == '{' ? J_OBJ : J_ARR;
        p++;
        jnode_t **tail = &n->child;
        ws();
        if (*p == close) { p++; return n; }
        for (;;) {
            char *key = NULL;
            ws();
            if (n->type == J_OBJ) {
                key = parse_str();
                ws();
                if (!key || *p != ':') goto fail;
                p++;
            }
            jnode_t *c = parse_val();
            if (!c) goto fail;
            c->key = key;
            *tail = c; tail = &c->next;
            ws();
            if (*p == ',') { p++; continue; }
            if (*p == close) { p++; return n; }
            goto fail;
        }
    } else if (*p == '"') {
        n->type = J_STR;
        if (!(n->str = parse_str())) goto fail;
        return n;
    } else if (!strncmp(p, "true", 4) || !strncmp(p, "false", 5)) {
        n->type = J_BOOL; n->num = *p == 't';
        p += *p == 't' ? 4 : 5;
        return n;
    } else if (!strncmp(p, "null", 4)) {
        n->type = J_NULL; p += 4;
        return n;
    } else {
        char *end;
        n->type = J_NUM; n->num = strtod(p, &end);
        if (end == p) goto fail;
        p = end;
        return n;
    }
fail:
    json_free(n);
    return NULL;
}

jnode_t *json_parse(char *text) { p = text; return parse_val(); }

jnode_t *json_get(const jnode_t *obj, const char *key)
{
    for (jnode_t *c = obj ? obj->child : NULL; c; c = c->next)
        if (c->key && !strcmp(c->key, key)) return c;
    return NULL;
}

size_t json_len(const jnode_t *arr)
{
    size_t n = 0;
    for (jnode_t *c = arr ? arr->child : NULL; c; c = c->next) n++;
    return n;
}

void json_free(jnode_t *n)
{
    while (n) {
        jnode_t *next = n->next;
        json_free(n->child);
        free(n);
        n = next;
    }
}

/* Just enough JSON to read firmware/test_vectors.json in the C tests (no escapes
 * beyond \" and \\; the vectors are ASCII and hex). */
#ifndef JSONMINI_H
#define JSONMINI_H
#include <stddef.h>

typedef enum { J_NULL, J_BOOL, J_NUM, J_STR, J_ARR, J_OBJ } jtype_t;
typedef struct jnode {
    jtype_t type;
    double num;
    char *str;            /* J_STR value, or the key when inside an object */
    char *key;
    struct jnode *child;  /* first element/member */
    struct jnode *next;
} jnode_t;

jnode_t *json_parse(char *text);          /* modifies text in place; NULL on error */
jnode_t *json_get(const jnode_t *obj, const char *key);
size_t json_len(const jnode_t *arr);
void json_free(jnode_t *n);
#endif

/* clothsim-params - prints the parameter table as Markdown (kernels/PARAMS.md is its output;
 * a test keeps the two equal), or with --schema as a JSON Schema (draft 2020-12; proto/params.schema.json
 * is its output, a test keeps those equal too), or with --openapi copies an OpenAPI document from
 * stdin to stdout with the live rows, as schema properties in YAML, between its marker lines
 * (OPENAPI_BEGIN ... OPENAPI_END: the Params schema of proto/openapi.yaml; docs.params_openapi). */
#include <stdio.h>
#include <string.h>

#include "clothsim/params.h"

static void value(const cs_param_info *p, const double *v)
{
    switch (p->type) {
    case CS_T_VEC3: printf("[%g, %g, %g]", v[0], v[1], v[2]); break;
    case CS_T_BOOL: printf("%s", v[0] != 0 ? "true" : "false"); break;
    case CS_T_ENUM: printf("%s", p->choices[(int)v[0]]); break;
    default: printf("%g", v[0]); break;
    }
}

static void json_str(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') printf("\\%c", c);
        else if (c < 0x20) printf("\\u%04x", c);
        else putchar(c);
    }
    putchar('"');
}

static void json_num(double v) { printf("%.15g", v); }

/* One property of the schema for row p. */
static void schema_property(const cs_param_info *p)
{
    printf("        ");
    json_str(p->name);
    printf(": {\n          \"description\": ");
    json_str(p->help);
    printf(",\n          \"x-unit\": ");
    json_str(p->unit);
    printf(",\n");
    switch (p->type) {
    case CS_T_ENUM:
        printf("          \"type\": \"string\",\n          \"enum\": [");
        for (int c = 0; p->choices[c]; c++) {
            printf("%s", c ? ", " : "");
            json_str(p->choices[c]);
        }
        printf("],\n          \"default\": ");
        json_str(p->choices[(int)p->def[0]]);
        break;
    case CS_T_BOOL:
        printf("          \"type\": \"boolean\",\n          \"default\": %s", p->def[0] != 0 ? "true" : "false");
        break;
    case CS_T_VEC3:
        printf("          \"type\": \"array\",\n          \"minItems\": 3,\n          \"maxItems\": 3,\n"
               "          \"items\": {\"type\": \"number\", \"minimum\": ");
        json_num(p->min);
        printf(", \"maximum\": ");
        json_num(p->max);
        printf("},\n          \"default\": [");
        for (int i = 0; i < 3; i++) {
            printf("%s", i ? ", " : "");
            json_num(p->def[i]);
        }
        printf("]");
        break;
    default:
        printf("          \"type\": \"%s\",\n          \"minimum\": ", p->type == CS_T_INT ? "integer" : "number");
        json_num(p->min);
        printf(",\n          \"maximum\": ");
        json_num(p->max);
        printf(",\n          \"default\": ");
        json_num(p->def[0]);
        break;
    }
    printf("\n        }");
}

static void schema_group(cs_param_kind kind, const char *title, const char *desc, int last)
{
    printf("    \"%s\": {\n      \"type\": \"object\",\n      \"description\": ", title);
    json_str(desc);
    printf(",\n      \"properties\": {\n");
    int n = 0;
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        if (p->kind != kind) continue;
        printf("%s", n++ ? ",\n" : "");
        schema_property(p);
    }
    printf("\n      }\n    }%s\n", last ? "" : ",");
}

/* A number YAML 1.1 readers take as one too: 1e-06 is a string to them, 1.0e-06 a float. */
static void yaml_num(double v)
{
    char text[40];
    snprintf(text, sizeof text, "%.15g", v);
    char *e = strchr(text, 'e');
    if (e && !strchr(text, '.')) printf("%.*s.0%s", (int)(e - text), text, e);
    else printf("%s", text);
}

/* Row p as an OpenAPI 3.1 schema property (the JSON Schema of schema_property, in YAML): its name
 * at `indent` spaces, its keywords two deeper. Strings are JSON-quoted (YAML double-quoted). */
static void openapi_property(const cs_param_info *p, int indent)
{
    const int in = indent + 2;
    printf("%*s%s:\n%*sdescription: ", indent, "", p->name, in, "");
    json_str(p->help);
    printf("\n%*sx-unit: ", in, "");
    json_str(p->unit);
    printf("\n");
    switch (p->type) {
    case CS_T_ENUM:
        printf("%*stype: string\n%*senum: [", in, "", in, "");
        for (int c = 0; p->choices[c]; c++) {
            printf("%s", c ? ", " : "");
            json_str(p->choices[c]);
        }
        printf("]\n%*sdefault: ", in, "");
        json_str(p->choices[(int)p->def[0]]);
        break;
    case CS_T_BOOL: printf("%*stype: boolean\n%*sdefault: %s", in, "", in, "", p->def[0] != 0 ? "true" : "false"); break;
    case CS_T_VEC3:
        printf("%*stype: array\n%*sminItems: 3\n%*smaxItems: 3\n%*sitems: {type: number, minimum: ", in, "", in, "", in, "",
               in, "");
        yaml_num(p->min);
        printf(", maximum: ");
        yaml_num(p->max);
        printf("}\n%*sdefault: [", in, "");
        for (int i = 0; i < 3; i++) {
            printf("%s", i ? ", " : "");
            yaml_num(p->def[i]);
        }
        printf("]");
        break;
    default:
        printf("%*stype: %s\n%*sminimum: ", in, "", p->type == CS_T_INT ? "integer" : "number", in, "");
        yaml_num(p->min);
        printf("\n%*smaximum: ", in, "");
        yaml_num(p->max);
        printf("\n%*sdefault: ", in, "");
        yaml_num(p->def[0]);
        break;
    }
    printf("\n");
}

#define OPENAPI_BEGIN "# BEGIN generated by clothsim-params --openapi"
#define OPENAPI_END "# END generated by clothsim-params --openapi"

/* stdin to stdout, the lines between the marker lines replaced by the live rows, each at the
 * BEGIN line's indentation. Both markers once, in order, or nothing is written and 1 returned. */
static int openapi(void)
{
    static char doc[1 << 22];
    const size_t len = fread(doc, 1, sizeof doc - 1, stdin);
    if (!feof(stdin) || ferror(stdin)) {
        fprintf(stderr, "clothsim-params --openapi: could not read stdin (at most %zu bytes)\n", sizeof doc - 1);
        return 1;
    }
    doc[len] = '\0';
    /* The line after BEGIN, and END's line. */
    char *end = NULL, *after_begin = NULL, *line_end = NULL;
    int nbegin = 0, nend = 0, indent = 0;
    for (char *l = doc; *l; l = line_end) {
        char *nl = strchr(l, '\n');
        line_end = nl ? nl + 1 : l + strlen(l);
        const char *t = l + strspn(l, " ");
        if (strncmp(t, OPENAPI_BEGIN, strlen(OPENAPI_BEGIN)) == 0) {
            nbegin++;
            after_begin = line_end;
            indent = (int)(t - l);
        } else if (strncmp(t, OPENAPI_END, strlen(OPENAPI_END)) == 0) {
            nend++;
            end = l;
        }
    }
    if (nbegin != 1 || nend != 1 || end < after_begin) {
        fprintf(stderr, "clothsim-params --openapi: stdin needs one line '%s...' and after it one line '%s...'\n",
                OPENAPI_BEGIN, OPENAPI_END);
        return 1;
    }
    fwrite(doc, 1, (size_t)(after_begin - doc), stdout);
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        if (p->kind == CS_KIND_LIVE) openapi_property(p, indent);
    }
    fputs(end, stdout);
    return 0;
}

static int schema(void)
{
    printf("{\n  \"$schema\": \"https://json-schema.org/draft/2020-12/schema\",\n"
           "  \"$id\": \"https://clothd.invalid/proto/params.schema.json\",\n"
           "  \"title\": \"clothsim parameters\",\n"
           "  \"description\": \"Generated by `clothsim-params --schema` from kernels/include/clothsim/params.h; do not edit. "
           "Ranges are inclusive and apply to each component of a vector; x-unit is the SI unit ('-' = none).\",\n"
           "  \"$defs\": {\n");
    schema_group(CS_KIND_LIVE, "Params", "Live parameters of the engine: applied at the next substep", 0);
    schema_group(CS_KIND_SCENE, "Scene", "Scene parameters of the engine: changing one rebuilds the cloth", 1);
    printf("  }\n}\n");
    return 0;
}

int main(int argc, char **argv)
{
    if (argc > 1 && strcmp(argv[1], "--schema") == 0) return schema();
    if (argc > 1 && strcmp(argv[1], "--openapi") == 0) return openapi();
    if (argc > 1) {
        fprintf(stderr, "usage: clothsim-params [--schema | --openapi < openapi.yaml]\n");
        return 2;
    }
    printf("# clothsim parameters\n\n"
           "Generated by `clothsim-params` from the table in `include/clothsim/params.h`; do not edit.\n"
           "`scene` parameters rebuild the cloth when changed; `live` ones apply at the next substep.\n"
           "Ranges are inclusive and apply to each component of a vector. clothd adds live settings of\n"
           "its own (pacing, automatic drops, checkpoints) and its startup settings: `clothd --help` and\n"
           "`GET /v1/params/schema` list the whole table.\n\n"
           "| name | type | unit | default | range | kind | meaning |\n"
           "|---|---|---|---|---|---|---|\n");
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        printf("| %s | %s | %s | ", p->name, cs_param_type_name(p->type), p->unit);
        value(p, p->def);
        printf(" | ");
        if (p->type == CS_T_ENUM) {
            for (int c = 0; p->choices[c]; c++) printf("%s%s", c ? ", " : "", p->choices[c]);
        } else if (p->type == CS_T_BOOL) {
            printf("true, false");
        } else {
            printf("%g .. %g", p->min, p->max);
        }
        printf(" | %s | %s |\n", cs_param_kind_name(p->kind), p->help);
    }
    return 0;
}

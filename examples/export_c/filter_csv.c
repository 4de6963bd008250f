/* filter_csv.c: filter a liemef log (CSV) in pure C99 with a filter exported by `liemef export-c`.
 *
 *   filter_csv LOG.csv OUT.csv [X0 [K0]]
 *
 * LOG.csv is a liemef log: a header line, then one row per sample time, `t, u_1..u_m, y_1..y_p` in this order
 * (as liemef.io.write_log writes it; `liemef schema SYSTEM` prints the columns). An empty field or `nan` is a
 * missing sample: a missing y component carries no information, a missing u holds the last input.
 * X0 is the initial estimate in the group's coordinates, comma separated (default: zeros); K0 the initial gain
 * K(0) = K0 * I (default 1). OUT.csv gets, at every sample time, t, the estimate's coordinates q1..qc and K's
 * diagonal, as liemef run's estimates.csv.
 *
 * Exits with status 1 and a message naming the line when the log cannot be read, or when the filter fails (a
 * non-zero status code; the rows before it are written). No heap: fixed-size arrays only.
 *
 * Build (FILTER is the export's --name, FILTER_UPPER the same in capitals):
 *   liemef export-c --system tse2 --out build
 *   cc -std=c99 -O2 -Wall -Wextra -Werror -pedantic -DFILTER=tse2 -DFILTER_UPPER=TSE2 -Ibuild filter_csv.c build/tse2.c -lm
 */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef FILTER
#define FILTER tse2
#define FILTER_UPPER TSE2
#endif

/* The export's names: F(_step) is tse2_step, U(_N) is TSE2_N, and its header is "tse2.h". */
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define F(x) CAT(FILTER, x)
#define U(x) CAT(FILTER_UPPER, x)
#define STR_(x) #x
#define STR(x) STR_(x)
#include STR(FILTER.h)

enum { N = U(_N), M = U(_INPUT_DIM), P = U(_OUTPUT_DIM), G = U(_GROUP_PARAMS), C = U(_COORDS_DIM) };
enum { COLUMNS = 1 + M + P, LINE_CHARS = 65536 };

/* The filter's state: in static storage, as on a microcontroller (no heap, nothing large on the stack). */
static F(_state) s;

static const char *const CAUSES[] = {"ok", "non-finite", "K not symmetric", "K not positive definite", "gate"};

/* A message on stderr; returns the exit status 1. */
static int fail(const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    fputs("filter_csv: ", stderr);
    vfprintf(stderr, fmt, args);
    fputc('\n', stderr);
    va_end(args);
    return 1;
}

/* Split a CSV line into its fields: each stored in v (at most n; empty or nan: NaN). Returns the number of
 * fields, or -k when field k (from 1) is neither a finite number nor empty/nan. */
static int parse_row(char *line, double *v, int n)
{
    char *p = line;
    int k = 0;
    for (;;) {
        char *end = p;
        while (*end != ',' && *end != '\0' && *end != '\n' && *end != '\r') end++;
        char stop = *end;
        *end = '\0';
        while (*p == ' ' || *p == '\t') p++;
        if (k < n) {
            char *rest = p;
            v[k] = (*p == '\0') ? NAN : strtod(p, &rest);
            while (*rest == ' ' || *rest == '\t') rest++;
            if ((*p != '\0' && rest == p) || *rest != '\0' || isinf(v[k])) return -(k + 1);
        }
        k++;
        if (stop != ',') return k;
        p = end + 1;
    }
}

/* One output row: t, the coordinates of the estimate, K's diagonal. */
static void write_row(FILE *out, double t, const F(_state) *st)
{
    double g[G], q[C];
    /* The estimate's group parameters are the state's first members (double arrays, in order: see the header). */
    memcpy(g, st, sizeof g);
    F(_coords)(g, q);
    fprintf(out, "%.17g", t);
    for (int i = 0; i < C; i++) fprintf(out, ",%.17g", q[i]);
    for (int i = 0; i < N; i++) fprintf(out, ",%.17g", st->K[i * N + i]);
    fputc('\n', out);
}

/* Read the log, filter it, write the estimates; returns the exit status. */
static int filter(FILE *in, FILE *out, const char *path)
{
    static char line[LINE_CHARS];
    double row[COLUMNS], prev[COLUMNS];
    long lineno = 0, rows = 0;
    int header = 1;
    fputs("t", out);
    for (int i = 0; i < C; i++) fprintf(out, ",q%d", i + 1);
    for (int i = 0; i < N; i++) fprintf(out, ",K_e%de%d", i, i);
    fputc('\n', out);
    while (fgets(line, sizeof line, in) != NULL) {
        lineno++;
        size_t len = strlen(line);
        if (len + 1 == sizeof line && line[len - 1] != '\n')
            return fail("%s: line %ld is longer than %d characters", path, lineno, LINE_CHARS - 2);
        if (strspn(line, " \t\r\n") == len) continue; /* a blank line */
        if (header) { /* the column names: only their number is checked */
            int k = 1;
            for (const char *c = line; *c; c++) k += (*c == ',');
            if (k != COLUMNS)
                return fail("%s: line %ld: expected a header of %d columns (t, %d inputs, %d outputs), got %d",
                            path, lineno, COLUMNS, M, P, k);
            header = 0;
            continue;
        }
        int k = parse_row(line, row, COLUMNS);
        if (k < 0) return fail("%s: line %ld: expected a finite number or an empty field (a missing sample) in column %d", path, lineno, -k);
        if (k != COLUMNS)
            return fail("%s: line %ld: expected %d values (t, %d inputs, %d outputs), got %d", path, lineno, COLUMNS,
                        M, P, k);
        if (!isfinite(row[0]) || (rows > 0 && !(row[0] > prev[0])))
            return fail("%s: line %ld: expected a finite time after the previous one, got %.17g", path, lineno,
                        row[0]);
        if (rows > 0) { /* the previous row's samples are used over [prev t, t], as by liemef's run */
            int code = F(_step)(&s, prev[0], row[0] - prev[0], prev + 1, prev + 1 + M, NULL);
            if (code != 0)
                return fail("%s: line %ld (t = %.17g): the filter failed over the interval to the next row: status "
                            "%d (%s); the estimates before it are written", path, lineno - 1, prev[0], code,
                            code > 0 && code < 5 ? CAUSES[code] : "?");
        }
        write_row(out, row[0], &s);
        memcpy(prev, row, sizeof row);
        rows++;
    }
    if (ferror(in)) return fail("cannot read %s after line %ld: %s", path, lineno, strerror(errno));
    if (rows < 1) return fail("%s: no samples (expected a header line, then rows t, u, y)", path);
    return 0;
}

int main(int argc, char **argv)
{
    double q0[C], g0[G], K0[N * N];
    if (argc < 3 || argc > 5) {
        fprintf(stderr, "usage: %s LOG.csv OUT.csv [X0 (%d coordinates, comma separated) [K0]]\n", argv[0], C);
        return 2;
    }
    for (int i = 0; i < C; i++) q0[i] = 0.0;
    if (argc > 3 && parse_row(argv[3], q0, C) != C)
        return fail("X0: expected %d comma-separated numbers, got '%s'", C, argv[3]);
    double k0 = 1.0;
    if (argc > 4) {
        char *rest;
        k0 = strtod(argv[4], &rest);
        if (rest == argv[4] || *rest != '\0' || !(k0 >= 0.0 && isfinite(k0)))
            return fail("K0: expected a number >= 0, got '%s'", argv[4]);
    }
    for (int i = 0; i < N * N; i++) K0[i] = (i % (N + 1) == 0) ? k0 : 0.0;
    F(_from_coords)(q0, g0);
    if (F(_init)(&s, g0, K0) != 0) return fail("X0, K0: expected finite numbers");

    FILE *in = fopen(argv[1], "r");
    if (in == NULL) return fail("cannot read %s: %s", argv[1], strerror(errno));
    FILE *out = fopen(argv[2], "w");
    if (out == NULL) {
        fclose(in);
        return fail("cannot write %s: %s", argv[2], strerror(errno));
    }
    int status = filter(in, out, argv[1]);
    fclose(in);
    if (fclose(out) != 0 && status == 0) status = fail("cannot write %s: %s", argv[2], strerror(errno));
    return status;
}

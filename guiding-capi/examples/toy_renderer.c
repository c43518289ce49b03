/*
 * toy_renderer.c: a toy "renderer" that embeds the guiding library through
 * its C ABI (include/guiding.h). Plain C99; built and run by
 * guiding-capi/tests/c_example.rs:
 *
 *   cc -std=c99 -Wall -Wextra -Werror -pedantic -I guiding-capi/include \
 *      guiding-capi/examples/toy_renderer.c target/release/libguiding_capi.a \
 *      -lpthread -ldl -lm -o toy_renderer
 *   ./toy_renderer [scratch-file-path [npm|nasg|df_nearest|df_linear [spp|time
 *                  [defect-medium-pdf]]]]
 *
 * Scene: shading points anywhere in the box [-1,1] x [-2,2] x [0,3]; the
 * incident radiance is 10 inside a small light cone around +z (cos theta >
 * 0.95) and a dim ambient 0.1 elsewhere, so the integral of the incident
 * radiance over the sphere is known: 10 * 2pi(1 - 0.95) + 0.1 * (4pi -
 * 2pi(1 - 0.95)).
 *
 * 1. Training, as the library's schedule (PgSchedule) says: a pass traces
 *    4096 one-vertex paths with uniformly sampled directions, recorded with a
 *    PgRecorder. Before each pass the renderer asks the schedule whether the
 *    training phase goes on; it traces the pass in pieces of the size the
 *    schedule asks for, and after each piece flushes its samples into the
 *    field, reports the piece's time and paths, and lets
 *    pg_field_train_scheduled run the Adam steps that are due.
 *    - spp (the default, and what the tests run): a budget of 150 passes, of
 *      which the first round(0.2 * 150) = 30 train (the estimates of step 2
 *      stand for the other 120), with PG_STEP_RULE_EPOCHS at 4 epochs: one
 *      update of clamp(ceil(4 * 4096 / 2048), 1, 8) = 8 steps per pass, the
 *      same on every run;
 *    - time: the library's default rule (a third of the training phase's
 *      wall clock trains, updates every 0.25 s of tracing) over a budget of
 *      2.5 s, of which the first 0.5 s train.
 * 2. Rendering: estimates the integral at 20000 random points with
 *    one-sample MIS between the guide (probability c, the field's selection
 *    probability) and uniform sampling, and with uniform sampling alone.
 * 3. Checks (exit status 1 on any failure):
 *    (a) sampled directions are unit vectors and pg_distributions_pdf of a
 *        sampled direction equals the pdf the sample came with;
 *    (b) the guided estimate is within 4 sigma of the exact integral and
 *        its variance is below half that of uniform sampling;
 *    (c) training went as scheduled: the passes of the training phase, the
 *        steps and updates of the schedule's report are the field's;
 *    (d) error paths: a NULL handle gives PG_NULL_POINTER and a message,
 *        too large an n PG_SIZE_MISMATCH, distributions used after an
 *        update PG_STALE, a missing file PG_IO and a corrupt one PG_FORMAT;
 *        a saved and loaded field gives identical samples and pdfs.
 *    (e) scattering points inside a medium: queries with a zero normal ("no
 *        surface"), the in-scattered radiance integral of L(w) p_HG(w) with a
 *        Henyey-Greenstein phase function (g = 0.7, forward +x: the light cone
 *        lies 90 degrees off the forward lobe), exact by quadrature, estimated
 *        with one-sample MIS of the guide times the vMF fit of the phase
 *        function (pg_hg_vmf_kappa, pg_distributions_apply_lobe_product; NPM,
 *        the plain guide otherwise) and phase sampling: unbiased within 4
 *        sigma, below half the variance of phase sampling alone. With a fourth
 *        argument "defect-medium-pdf" the MIS density uses the guide without
 *        the product (a sample / pdf mismatch): the negative control of (e),
 *        which c_example.rs runs and expects to fail.
 */
/* clock_gettime (POSIX) under -std=c99. */
#define _POSIX_C_SOURCE 199309L

#include "guiding.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define PI_F 3.14159265358979f
#define INV_FOUR_PI_F (1.0f / (4.0f * PI_F))
#define PATHS_PER_PASS 4096
/* The spp budget and the passes of its training phase (train_fraction 0.2). */
#define BUDGET_SPP 150
#define TRAINING_PASSES 30
#define BUDGET_SECONDS 2.5
#define ESTIMATES 20000
#define BATCH 1000

static const float BOX_MIN[3] = {-1.0f, -2.0f, 0.0f};
static const float BOX_MAX[3] = {1.0f, 2.0f, 3.0f};

static int failures = 0;

#define CHECK(cond, ...)                                                   \
    do {                                                                   \
        if (!(cond)) {                                                     \
            fprintf(stderr, "FAILED %s:%d: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                  \
            fprintf(stderr, "\n");                                         \
            failures++;                                                    \
        }                                                                  \
    } while (0)

/* A call that must succeed: on failure print the library's message and stop. */
#define TRY(call)                                                          \
    do {                                                                   \
        PgStatus status_ = (call);                                         \
        if (status_ != PG_OK) {                                            \
            fprintf(stderr, "FAILED %s:%d: %s returned %d: %s\n", __FILE__, \
                    __LINE__, #call, (int)status_, pg_last_error());       \
            exit(1);                                                       \
        }                                                                  \
    } while (0)

/* PCG32 (O'Neill 2014), the generator of the Rust tests. */
typedef struct {
    uint64_t state;
    uint64_t inc;
} Rng;

static uint32_t rng_next(Rng *r) {
    uint64_t old = r->state;
    uint32_t xorshifted, rot;
    r->state = old * 6364136223846793005ULL + r->inc;
    xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
}

static Rng rng_new(uint64_t seed, uint64_t stream) {
    Rng r;
    r.state = 0;
    r.inc = (stream << 1u) | 1u;
    rng_next(&r);
    r.state += seed;
    rng_next(&r);
    return r;
}

/* Uniform in [0, 1). */
static float rng_float(Rng *r) { return (float)(rng_next(r) >> 8) * (1.0f / 16777216.0f); }

static void uniform_sphere(float u1, float u2, float out[3]) {
    float z = 1.0f - 2.0f * u1;
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    float phi = 2.0f * PI_F * u2;
    out[0] = r * cosf(phi);
    out[1] = r * sinf(phi);
    out[2] = z;
}

/* The scene's incident radiance: the light cone around +z and the ambient. */
static float radiance(const float dir[3]) { return dir[2] > 0.95f ? 10.0f : 0.1f; }

static double radiance_integral(void) {
    const double pi = 3.14159265358979323846;
    double cone = 2.0 * pi * 0.05;
    return 10.0 * cone + 0.1 * (4.0 * pi - cone);
}

static PgQueryPoint random_query(Rng *rng) {
    PgQueryPoint q;
    int k;
    memset(&q, 0, sizeof q);
    for (k = 0; k < 3; k++) {
        q.position[k] = BOX_MIN[k] + (BOX_MAX[k] - BOX_MIN[k]) * rng_float(rng);
    }
    q.roughness = 1.0f;
    uniform_sphere(rng_float(rng), rng_float(rng), q.normal);
    uniform_sphere(rng_float(rng), rng_float(rng), q.wo);
    return q;
}

static float length3(const float v[3]) { return sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

static double now_seconds(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Traces n one-vertex paths with uniform directions, recorded in `recorder`. */
static void trace_paths(PgRecorder *recorder, Rng *rng, uint64_t n) {
    uint64_t i;
    for (i = 0; i < n; i++) {
        PgQueryPoint q = random_query(rng);
        PgPathVertex v;
        float escaped[3];
        TRY(pg_path_vertex_set_defaults(&v));
        memcpy(v.position, q.position, sizeof v.position);
        memcpy(v.normal, q.normal, sizeof v.normal);
        memcpy(v.wo, q.wo, sizeof v.wo);
        uniform_sphere(rng_float(rng), rng_float(rng), v.wi);
        v.sample_pdf = INV_FOUR_PI_F;
        v.bsdf_pdf = INV_FOUR_PI_F;
        v.bsdf_cos[0] = v.bsdf_cos[1] = v.bsdf_cos[2] = 1.0f;
        escaped[0] = escaped[1] = escaped[2] = radiance(v.wi);
        TRY(pg_recorder_start_path(recorder));
        TRY(pg_recorder_add_vertex(recorder, &v));
        TRY(pg_recorder_add_escaped_radiance(recorder, escaped, 1.0f));
        TRY(pg_recorder_end_path(recorder, NULL));
    }
}

/* 1. The training phase as the schedule says: passes while it lasts, each
 * traced in pieces, every piece flushed, reported and followed by the steps
 * that are due. Returns the passes traced; adds the paths to *paths. */
static uint32_t train(PgField *field, PgRecorder *recorder, PgSchedule *schedule, Rng *rng,
                      uint64_t *paths) {
    double start = now_seconds();
    uint32_t pass;
    uint64_t pieces = 0, updates = 0;
    for (pass = 0;; pass++) {
        bool training = false;
        uint64_t done = 0;
        TRY(pg_schedule_in_training_phase(schedule, now_seconds() - start, pass, &training));
        if (!training) {
            break;
        }
        while (done < PATHS_PER_PASS) {
            uint64_t piece = 0;
            size_t handed_over = 0;
            double t0 = now_seconds();
            PgUpdateReport report;
            TRY(pg_schedule_paths_before_update(schedule, PATHS_PER_PASS, &piece));
            CHECK(piece >= 1 && piece <= PATHS_PER_PASS, "piece of %llu paths",
                  (unsigned long long)piece);
            if (piece > PATHS_PER_PASS - done) {
                piece = PATHS_PER_PASS - done;
            }
            trace_paths(recorder, rng, piece);
            TRY(pg_recorder_flush_into(recorder, field, &handed_over));
            CHECK(handed_over == piece, "%zu samples handed over for %llu paths", handed_over,
                  (unsigned long long)piece);
            TRY(pg_schedule_record_traced(schedule, now_seconds() - t0, piece));
            TRY(pg_field_train_scheduled(field, schedule, &report));
            CHECK(report.skipped_steps == 0, "update: %u steps, %u skipped", report.steps,
                  report.skipped_steps);
            updates += report.steps > 0;
            done += piece;
            pieces++;
        }
        *paths += done;
    }
    printf("training phase: %u passes in %llu pieces, %llu updates\n", pass,
           (unsigned long long)pieces, (unsigned long long)updates);
    return pass;
}

/* One fixed update outside the schedule: trace a pass, flush, pg_field_update. */
static void trace_and_update(PgField *field, PgRecorder *recorder, Rng *rng) {
    size_t handed_over = 0;
    PgUpdateReport report;
    trace_paths(recorder, rng, PATHS_PER_PASS);
    TRY(pg_recorder_flush_into(recorder, field, &handed_over));
    CHECK(handed_over == PATHS_PER_PASS, "%zu samples handed over", handed_over);
    TRY(pg_field_update(field, &report));
    CHECK(report.steps > 0 && report.skipped_steps == 0, "update: %u steps, %u skipped",
          report.steps, report.skipped_steps);
}

/* Running sums of an estimator. */
typedef struct {
    double sum, sum2;
    long n;
} Moments;

static void add(Moments *m, double x) {
    m->sum += x;
    m->sum2 += x * x;
    m->n++;
}
static double mean(const Moments *m) { return m->sum / (double)m->n; }
static double variance(const Moments *m) {
    double mu = mean(m);
    return m->sum2 / (double)m->n - mu * mu;
}

static PgQueryPoint queries[BATCH];
static float u[2 * BATCH], guide_dirs[3 * BATCH], guide_pdfs[BATCH], check_pdfs[BATCH];
static float selection[BATCH], dirs[3 * BATCH], pdfs[BATCH];

/* Renders ESTIMATES one-sample estimates with the guide and with uniform
 * sampling; checks (a) on every guided sample. */
static void render(PgField *field, PgDistributions *dists, Rng *rng, Moments *guided,
                   Moments *uniform) {
    int start, i;
    int bad_lanes = 0;
    double worst_rel = 0.0, worst_len = 0.0;
    for (start = 0; start < ESTIMATES; start += BATCH) {
        size_t len = 0;
        for (i = 0; i < BATCH; i++) {
            queries[i] = random_query(rng);
            u[2 * i] = rng_float(rng);
            u[2 * i + 1] = rng_float(rng);
        }
        TRY(pg_field_query(field, BATCH, queries, dists));
        TRY(pg_distributions_len(dists, &len));
        CHECK(len == BATCH, "%zu distributions", len);
        TRY(pg_distributions_selection_probability(dists, BATCH, selection));
        TRY(pg_distributions_sample(dists, BATCH, u, guide_dirs, guide_pdfs));
        /* (a) unit directions, and pdf(sampled direction) == sample pdf. */
        TRY(pg_distributions_pdf(dists, BATCH, guide_dirs, check_pdfs));
        for (i = 0; i < BATCH; i++) {
            double rel = fabs((double)check_pdfs[i] / (double)guide_pdfs[i] - 1.0);
            double len_err = fabs((double)length3(&guide_dirs[3 * i]) - 1.0);
            /* Written so that NaN counts as bad. */
            if (!(guide_pdfs[i] > 0.0f && rel < 1e-3 && len_err < 1e-5)) {
                bad_lanes++;
            }
            worst_rel = rel > worst_rel ? rel : worst_rel;
            worst_len = len_err > worst_len ? len_err : worst_len;
        }
        /* One-sample MIS: the guide with probability c, uniform otherwise. */
        for (i = 0; i < BATCH; i++) {
            if (rng_float(rng) < selection[i]) {
                memcpy(&dirs[3 * i], &guide_dirs[3 * i], 3 * sizeof(float));
            } else {
                uniform_sphere(rng_float(rng), rng_float(rng), &dirs[3 * i]);
            }
        }
        TRY(pg_distributions_pdf(dists, BATCH, dirs, pdfs));
        for (i = 0; i < BATCH; i++) {
            float c = selection[i];
            float pdf = c * pdfs[i] + (1.0f - c) * INV_FOUR_PI_F;
            float d[3];
            add(guided, (double)(radiance(&dirs[3 * i]) / pdf));
            uniform_sphere(rng_float(rng), rng_float(rng), d);
            add(uniform, (double)(radiance(d) / INV_FOUR_PI_F));
        }
    }
    printf("(a) %d guided samples: worst |pdf(dir)/pdf - 1| = %.2e, worst ||dir| - 1| = %.2e, "
           "%d bad\n",
           ESTIMATES, worst_rel, worst_len, bad_lanes);
    CHECK(bad_lanes == 0, "%d samples with a non-unit direction or a pdf that pdf(dir) does not "
          "reproduce within 1e-3", bad_lanes);
}

static int message_is_set(void) { return pg_last_error()[0] != '\0'; }

/* (d) NULL handles and too large counts. */
static void check_argument_errors(PgField *field, PgDistributions *dists) {
    PgFieldStats stats;
    float out[4];
    size_t len = 0;
    CHECK(pg_field_update(NULL, NULL) == PG_NULL_POINTER, "update(NULL)");
    CHECK(message_is_set(), "no message after update(NULL)");
    printf("(d) pg_field_update(NULL): \"%s\"\n", pg_last_error());
    CHECK(pg_field_stats(field, NULL) == PG_NULL_POINTER && message_is_set(), "stats(.., NULL)");
    CHECK(pg_field_stats(NULL, &stats) == PG_NULL_POINTER && message_is_set(), "stats(NULL, ..)");
    CHECK(pg_distributions_sample(NULL, 0, NULL, NULL, NULL) == PG_NULL_POINTER,
          "distributions_sample(NULL)");
    /* n = 0 with NULL arrays is fine, and a success clears the message. */
    CHECK(pg_field_sample(field, 0, NULL, NULL, NULL, NULL) == PG_OK, "n = 0");
    CHECK(!message_is_set(), "message left after a success: %s", pg_last_error());
    TRY(pg_distributions_len(dists, &len));
    CHECK(pg_distributions_selection_probability(dists, len + 1, NULL) == PG_NULL_POINTER,
          "NULL out with n > 0");
    {
        float *big = (float *)calloc(len + 1, sizeof(float));
        CHECK(big != NULL, "out of memory");
        if (big != NULL) {
            CHECK(pg_distributions_selection_probability(dists, len + 1, big) ==
                      PG_SIZE_MISMATCH,
                  "n = len + 1");
            printf("(d) n = len + 1: \"%s\"\n", pg_last_error());
            free(big);
        }
    }
    /* Overlapping outputs are refused. */
    {
        float uu[2] = {0.5f, 0.5f};
        CHECK(pg_distributions_sample(dists, 1, uu, out, out + 2) == PG_INVALID_ARGUMENT,
              "overlapping dirs and pdfs");
    }
}

/* (d) Distributions decoded before an update are stale afterwards. */
static void check_stale(PgField *field, PgRecorder *recorder, PgDistributions *dists, Rng *rng) {
    float uu[2] = {0.25f, 0.75f}, d[3], p;
    PgQueryPoint q = random_query(rng);
    TRY(pg_field_query(field, 1, &q, dists));
    TRY(pg_distributions_sample(dists, 1, uu, d, &p));
    trace_and_update(field, recorder, rng);
    CHECK(pg_distributions_sample(dists, 1, uu, d, &p) == PG_STALE, "sample after update");
    CHECK(message_is_set(), "no message for PG_STALE");
    printf("(d) after update: \"%s\"\n", pg_last_error());
    CHECK(pg_distributions_pdf(dists, 1, d, &p) == PG_STALE, "pdf after update");
    TRY(pg_field_query(field, 1, &q, dists));
    CHECK(pg_distributions_sample(dists, 1, uu, d, &p) == PG_OK, "sample after re-query");
}

/* (d) Save, load, identical answers; missing and corrupt files. */
static void check_save_load(PgField *field, const char *path, Rng *rng) {
    PgField *loaded = NULL;
    PgField *missing = NULL;
    FILE *f;
    int i, same = 1;
    static float dirs_a[3 * BATCH], dirs_b[3 * BATCH], pdf_a[BATCH], pdf_b[BATCH];
    TRY(pg_field_save(field, path));
    TRY(pg_field_load(path, &loaded));
    for (i = 0; i < BATCH; i++) {
        queries[i] = random_query(rng);
        u[2 * i] = rng_float(rng);
        u[2 * i + 1] = rng_float(rng);
    }
    TRY(pg_field_sample(field, BATCH, queries, u, dirs_a, pdf_a));
    TRY(pg_field_sample(loaded, BATCH, queries, u, dirs_b, pdf_b));
    same = memcmp(dirs_a, dirs_b, sizeof dirs_a) == 0 && memcmp(pdf_a, pdf_b, sizeof pdf_a) == 0;
    TRY(pg_field_pdf(field, BATCH, queries, dirs_a, pdf_a));
    TRY(pg_field_pdf(loaded, BATCH, queries, dirs_a, pdf_b));
    same = same && memcmp(pdf_a, pdf_b, sizeof pdf_a) == 0;
    CHECK(same, "the loaded field answers differently");
    printf("(d) save + load: %d samples and pdfs %s\n", BATCH, same ? "identical" : "DIFFER");
    pg_field_release(loaded);

    /* A corrupt file: flip one byte in the middle. */
    f = fopen(path, "r+b");
    CHECK(f != NULL, "cannot reopen %s", path);
    if (f != NULL) {
        long size;
        int c;
        fseek(f, 0, SEEK_END);
        size = ftell(f);
        fseek(f, size / 2, SEEK_SET);
        c = fgetc(f);
        fseek(f, size / 2, SEEK_SET);
        fputc(c ^ 0x10, f);
        fclose(f);
        CHECK(pg_field_load(path, &missing) == PG_FORMAT && missing == NULL, "corrupt file");
        printf("(d) corrupt file: \"%s\"\n", pg_last_error());
    }
    remove(path);
    CHECK(pg_field_load(path, &missing) == PG_IO && missing == NULL, "missing file");
    CHECK(message_is_set(), "no message for PG_IO");
}

/* The medium of check (e): Henyey-Greenstein with asymmetry MEDIUM_G around the forward +x. */
#define MEDIUM_G 0.7f
static const float FORWARD[3] = {1.0f, 0.0f, 0.0f};

static double hg_density(double g, double cos_theta) {
    double d = 1.0 + g * g - 2.0 * g * cos_theta;
    return (1.0 - g * g) / (4.0 * 3.14159265358979323846 * d * sqrt(d));
}

/* A direction of the HG phase function around FORWARD (= +x), and its density. */
static float sample_hg(float u1, float u2, float out[3]) {
    float g = MEDIUM_G;
    float s = (1.0f - g * g) / (1.0f - g + 2.0f * g * u1);
    float c = fminf(1.0f, fmaxf(-1.0f, (1.0f + g * g - s * s) / (2.0f * g)));
    float r = sqrtf(fmaxf(0.0f, 1.0f - c * c));
    float phi = 2.0f * PI_F * u2;
    /* Local frame: FORWARD = +x, then y and z. */
    out[0] = c;
    out[1] = r * cosf(phi);
    out[2] = r * sinf(phi);
    return (float)hg_density(g, c);
}

/* The exact in-scattered integral: 0.1 + 9.9 times the HG mass in the light cone
 * (cos theta > 0.95 around +z), by the midpoint rule over the cone (1000 x 1000). */
static double in_scattered_integral(void) {
    const double pi = 3.14159265358979323846;
    const int n = 1000;
    double mass = 0.0;
    int i, j;
    for (i = 0; i < n; i++) {
        double mu = 0.95 + 0.05 * (i + 0.5) / n;
        double st = sqrt(1.0 - mu * mu);
        for (j = 0; j < n; j++) {
            double phi = 2.0 * pi * (j + 0.5) / n;
            mass += hg_density((double)MEDIUM_G, st * cos(phi));
        }
    }
    mass *= (0.05 / n) * (2.0 * pi / n);
    return 0.1 + 9.9 * mass;
}

/* (e) The in-scattered radiance at points inside a medium, guided (times the phase lobe
 * for NPM) in one-sample MIS with phase sampling, against phase sampling alone. */
static void render_medium(PgField *field, PgDistributions *dists, Rng *rng,
                          PgRepresentation representation, int defect) {
    static float axes[3 * BATCH], kappas[BATCH];
    Moments guided = {0.0, 0.0, 0}, phase = {0.0, 0.0, 0};
    double exact = in_scattered_integral(), sigma;
    float kappa = 0.0f;
    int start, i, k;
    TRY(pg_hg_vmf_kappa(MEDIUM_G, &kappa));
    for (start = 0; start < ESTIMATES; start += BATCH) {
        for (i = 0; i < BATCH; i++) {
            queries[i] = random_query(rng);
            for (k = 0; k < 3; k++) {
                queries[i].normal[k] = 0.0f; /* no surface */
                queries[i].wo[k] = -FORWARD[k];
                axes[3 * i + k] = FORWARD[k];
            }
            kappas[i] = kappa;
            u[2 * i] = rng_float(rng);
            u[2 * i + 1] = rng_float(rng);
        }
        TRY(pg_field_query(field, BATCH, queries, dists));
        if (representation == PG_REPRESENTATION_NPM) {
            TRY(pg_distributions_apply_lobe_product(dists, BATCH, axes, kappas));
        }
        TRY(pg_distributions_selection_probability(dists, BATCH, selection));
        TRY(pg_distributions_sample(dists, BATCH, u, guide_dirs, guide_pdfs));
        for (i = 0; i < BATCH; i++) {
            if (rng_float(rng) < selection[i]) {
                memcpy(&dirs[3 * i], &guide_dirs[3 * i], 3 * sizeof(float));
            } else {
                sample_hg(rng_float(rng), rng_float(rng), &dirs[3 * i]);
            }
        }
        if (defect) {
            /* The negative control: the density of the guide without the product. */
            TRY(pg_field_query(field, BATCH, queries, dists));
        }
        TRY(pg_distributions_pdf(dists, BATCH, dirs, pdfs));
        for (i = 0; i < BATCH; i++) {
            float c = selection[i], d[3];
            double p_phase = hg_density((double)MEDIUM_G, (double)dirs[3 * i]);
            double pdf = (double)c * (double)pdfs[i] + (1.0 - (double)c) * p_phase;
            double p_alone;
            add(&guided, (double)radiance(&dirs[3 * i]) * p_phase / pdf);
            p_alone = sample_hg(rng_float(rng), rng_float(rng), d);
            add(&phase, (double)radiance(d) * hg_density((double)MEDIUM_G, (double)d[0]) /
                            (double)p_alone);
        }
    }
    sigma = sqrt(variance(&guided) / (double)guided.n);
    printf("(e) medium: exact %.5f; guided mean %.5f (%.2f sigma) variance %.4f; phase "
           "sampling mean %.5f variance %.4f; variance ratio %.3f\n",
           exact, mean(&guided), fabs(mean(&guided) - exact) / sigma, variance(&guided),
           mean(&phase), variance(&phase), variance(&guided) / variance(&phase));
    CHECK(fabs(mean(&guided) - exact) < 4.0 * sigma, "medium estimate %.5f vs exact %.5f",
          mean(&guided), exact);
    CHECK(variance(&guided) < 0.5 * variance(&phase), "medium variance %.4f vs phase %.4f",
          variance(&guided), variance(&phase));
}

static int representation_of(const char *name, PgRepresentation *out) {
    static const char *const names[4] = {"npm", "nasg", "df_nearest", "df_linear"};
    static const PgRepresentation codes[4] = {PG_REPRESENTATION_NPM, PG_REPRESENTATION_NASG,
                                              PG_REPRESENTATION_DF_NEAREST,
                                              PG_REPRESENTATION_DF_LINEAR};
    int i;
    for (i = 0; i < 4; i++) {
        if (strcmp(name, names[i]) == 0) {
            *out = codes[i];
            return 1;
        }
    }
    return 0;
}

int main(int argc, char **argv) {
    const char *scratch = argc > 1 ? argv[1] : "toy_renderer.guide";
    const char *name = argc > 2 ? argv[2] : "npm";
    const char *budget = argc > 3 ? argv[3] : "spp";
    int by_time = strcmp(budget, "time") == 0;
    int defect_medium_pdf = argc > 4 && strcmp(argv[4], "defect-medium-pdf") == 0;
    PgRepresentation representation;
    PgFieldArgs args;
    PgScheduleArgs schedule_args;
    PgField *field = NULL;
    PgRecorder *recorder = NULL;
    PgDistributions *dists = NULL;
    PgSchedule *schedule = NULL;
    PgFieldStats stats;
    PgScheduleReport sr;
    uint64_t paths = 0;
    uint32_t passes;
    Moments guided = {0.0, 0.0, 0}, uniform = {0.0, 0.0, 0};
    Rng rng = rng_new(11, 1);
    double exact = radiance_integral();
    double mean_g, var_g, var_u, sigma;
    int k;

    if (!representation_of(name, &representation)) {
        fprintf(stderr, "unknown representation %s (npm, nasg, df_nearest, df_linear)\n", name);
        return 2;
    }
    if (!by_time && strcmp(budget, "spp") != 0) {
        fprintf(stderr, "unknown budget %s (spp, time)\n", budget);
        return 2;
    }
    printf("guiding %s, representation %s, %s budget\n", pg_version(), name, budget);
    TRY(pg_field_args_set_defaults(&args, representation));
    args.size = PG_SIZE_SMALL;
    args.selection_probability = 0.7f;
    args.learning_rate = 2e-2f;
    args.batch_size = 2048;
    args.steps_per_update = 8;
    args.threads = 2;
    args.seed = 1;
    for (k = 0; k < 3; k++) {
        args.bounds_min[k] = BOX_MIN[k];
        args.bounds_max[k] = BOX_MAX[k];
    }
    TRY(pg_field_new(&args, &field));
    TRY(pg_recorder_new(&recorder));
    TRY(pg_distributions_new(&dists));
    /* The library's schedule with the render's budget. */
    TRY(pg_schedule_args_set_defaults(&schedule_args));
    if (by_time) {
        schedule_args.budget_kind = PG_BUDGET_SECONDS;
        schedule_args.budget = BUDGET_SECONDS;
    } else {
        schedule_args.budget_kind = PG_BUDGET_SPP;
        schedule_args.budget = BUDGET_SPP;
        schedule_args.step_rule = PG_STEP_RULE_EPOCHS;
        schedule_args.step_value = 4.0;
    }
    TRY(pg_schedule_new(&schedule_args, &schedule));

    /* 1. Training. */
    passes = train(field, recorder, schedule, &rng, &paths);
    TRY(pg_schedule_report(schedule, &sr));
    pg_schedule_release(schedule);
    TRY(pg_field_stats(field, &stats));
    printf("trained: %llu steps, %llu samples accepted, %llu rejected, generation %llu, "
           "%llu parameters\n",
           (unsigned long long)stats.steps, (unsigned long long)stats.accepted_samples,
           (unsigned long long)(stats.rejected_samples[0] + stats.rejected_samples[1] +
                                stats.rejected_samples[2] + stats.rejected_samples[3]),
           (unsigned long long)stats.generation, (unsigned long long)stats.param_count);
    printf("schedule: %llu updates, %llu steps of %.3f ms; tracing %.3f s, training %.3f s "
           "(share %.2f)\n",
           (unsigned long long)sr.updates, (unsigned long long)sr.steps,
           1e3 * sr.seconds_per_step, sr.traced_seconds, sr.trained_seconds, sr.training_share);
    /* (c) Training went as scheduled. */
    CHECK(stats.accepted_samples == paths && paths == (uint64_t)passes * PATHS_PER_PASS,
          "accepted %llu of %llu paths", (unsigned long long)stats.accepted_samples,
          (unsigned long long)paths);
    CHECK(sr.training_over == 1, "training phase not over");
    CHECK(stats.steps == sr.steps, "field %llu steps, schedule %llu",
          (unsigned long long)stats.steps, (unsigned long long)sr.steps);
    CHECK(stats.generation == sr.updates, "generation %llu, %llu updates",
          (unsigned long long)stats.generation, (unsigned long long)sr.updates);
    if (by_time) {
        CHECK(passes >= 1 && sr.updates >= 1, "%u passes, %llu updates", passes,
              (unsigned long long)sr.updates);
    } else {
        /* The same training on every run: 30 passes, one update of 8 steps each. */
        CHECK(passes == TRAINING_PASSES, "%u training passes", passes);
        CHECK(sr.updates == TRAINING_PASSES && sr.steps == 8 * TRAINING_PASSES,
              "%llu updates, %llu steps", (unsigned long long)sr.updates,
              (unsigned long long)sr.steps);
    }

    /* 2. Rendering, with check (a). */
    render(field, dists, &rng, &guided, &uniform);

    /* (b) Unbiased, and less than half the variance of uniform sampling. */
    mean_g = mean(&guided);
    var_g = variance(&guided);
    var_u = variance(&uniform);
    sigma = sqrt(var_g / (double)guided.n);
    printf("(b) exact %.4f; guided mean %.4f (%.2f sigma) variance %.3f; uniform mean %.4f "
           "variance %.3f; variance ratio %.3f\n",
           exact, mean_g, fabs(mean_g - exact) / sigma, var_g, mean(&uniform), var_u,
           var_g / var_u);
    CHECK(fabs(mean_g - exact) < 4.0 * sigma, "guided estimate %.4f vs exact %.4f", mean_g, exact);
    CHECK(var_g < 0.5 * var_u, "guided variance %.3f vs uniform %.3f", var_g, var_u);

    /* (e) Scattering points inside a medium. */
    render_medium(field, dists, &rng, representation, defect_medium_pdf);

    /* (d) Error paths. */
    check_argument_errors(field, dists);
    check_stale(field, recorder, dists, &rng);
    check_save_load(field, scratch, &rng);

    /* The distributions keep the field alive: release the field first. */
    pg_field_release(field);
    {
        float uu[2] = {0.5f, 0.5f}, d[3], p;
        CHECK(pg_distributions_sample(dists, 1, uu, d, &p) == PG_OK,
              "distributions outlive their field");
    }
    pg_distributions_release(dists);
    pg_recorder_release(recorder);
    pg_field_release(NULL);

    if (failures > 0) {
        printf("toy_renderer: %d check(s) FAILED\n", failures);
        return 1;
    }
    printf("toy_renderer: all checks passed\n");
    return 0;
}

/* Embree 3 closest-hit timing on a ray file written by Opal's `accel_rays` example.
 *
 * File (little endian): magic "OPALRAY1", u32 triangle count, u32 ray count, then per triangle
 * 9 f32 (three corners), then per ray 7 f32 (origin, direction, tmax).
 *
 * Builds an Embree scene from the triangle soup (one RTC_GEOMETRY_TYPE_TRIANGLE geometry,
 * default build quality RTC_BUILD_QUALITY_MEDIUM, device config "threads=N"), then traces every
 * ray with rtcIntersect1 (tnear 0; flush-to-zero and denormals-are-zero on, as Embree
 * recommends) on N pthreads taking chunks of 4096 rays from a shared
 * counter, R times. Prints one line in the format `accel_vs_embree.sh` parses:
 *   RESULT embree <label> tris=.. rays=.. build_ms=<median> mrays_s=<median> min=.. max=..
 *          cpu_mrays_s=<median> hits=.. tsum=..
 * (cpu_mrays_s = rays per CPU-second of the process, robust to other jobs on the machine;
 * hits = rays with a hit, tsum = sum of the hit distances in double: the checksum Opal prints).
 *
 * Usage: rays FILE LABEL [THREADS=2] [REPEATS=7]
 * Build: bench/embree/build.sh (cc -O2 rays.c -lembree3 -lpthread). Embree is only used here,
 * never by Opal. */
#define _POSIX_C_SOURCE 200809L
#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <pmmintrin.h>
#include <xmmintrin.h>

#define CHUNK 4096

static float *g_tris;
static float *g_rays;
static uint32_t g_ntris, g_nrays;
static RTCScene g_scene;
static atomic_size_t g_next;

typedef struct {
  size_t hits;
  double tsum;
} Tally;

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

/* CPU seconds (user + system) of this process. */
static double cpu_now(void) {
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_utime.tv_sec + 1e-6 * ru.ru_utime.tv_usec + ru.ru_stime.tv_sec + 1e-6 * ru.ru_stime.tv_usec;
}

static void on_error(void *user, enum RTCError code, const char *msg) {
  (void)user;
  fprintf(stderr, "embree error %d: %s\n", (int)code, msg);
  exit(1);
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

static double median(double *v, int n) {
  qsort(v, n, sizeof(double), cmp_double);
  return v[n / 2];
}

static void read_file(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) { perror(path); exit(1); }
  char magic[8];
  if (fread(magic, 1, 8, f) != 8 || memcmp(magic, "OPALRAY1", 8) != 0) {
    fprintf(stderr, "%s: not an OPALRAY1 file\n", path);
    exit(1);
  }
  if (fread(&g_ntris, 4, 1, f) != 1 || fread(&g_nrays, 4, 1, f) != 1) { fprintf(stderr, "%s: truncated\n", path); exit(1); }
  g_tris = malloc((size_t)g_ntris * 9 * sizeof(float));
  g_rays = malloc((size_t)g_nrays * 7 * sizeof(float));
  if (fread(g_tris, sizeof(float) * 9, g_ntris, f) != g_ntris || fread(g_rays, sizeof(float) * 7, g_nrays, f) != g_nrays) {
    fprintf(stderr, "%s: truncated\n", path);
    exit(1);
  }
  fclose(f);
}

/* Triangle soup: three vertices per triangle, as Opal's Bvh gets it. */
static RTCScene build(RTCDevice dev) {
  RTCScene scene = rtcNewScene(dev);
  RTCGeometry geom = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), (size_t)g_ntris * 3);
  unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), g_ntris);
  memcpy(vb, g_tris, (size_t)g_ntris * 9 * sizeof(float));
  for (size_t i = 0; i < (size_t)g_ntris * 3; i++) ib[i] = (unsigned)i;
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(scene);
  return scene;
}

/* Embree's recommended setting for every thread that builds or traces. */
static void set_ftz_daz(void) {
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
}

static void *worker(void *arg) {
  Tally *t = arg;
  set_ftz_daz();
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  size_t hits = 0;
  double tsum = 0.0;
  for (;;) {
    size_t start = atomic_fetch_add(&g_next, CHUNK);
    if (start >= g_nrays) break;
    size_t end = start + CHUNK < g_nrays ? start + CHUNK : g_nrays;
    for (size_t i = start; i < end; i++) {
      const float *r = g_rays + 7 * i;
      struct RTCRayHit rh;
      rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2];
      rh.ray.dir_x = r[3]; rh.ray.dir_y = r[4]; rh.ray.dir_z = r[5];
      rh.ray.tnear = 0.0f;
      rh.ray.tfar = r[6];
      rh.ray.time = 0.0f;
      rh.ray.mask = 0xFFFFFFFFu;
      rh.ray.id = 0;
      rh.ray.flags = 0;
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
      rtcIntersect1(g_scene, &ctx, &rh);
      if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
        hits++;
        tsum += rh.ray.tfar;
      }
    }
  }
  t->hits = hits;
  t->tsum = tsum;
  return NULL;
}

static Tally trace_all(int threads) {
  pthread_t th[256];
  Tally tal[256];
  atomic_store(&g_next, 0);
  for (int i = 0; i < threads; i++) pthread_create(&th[i], NULL, worker, &tal[i]);
  Tally sum = {0, 0.0};
  for (int i = 0; i < threads; i++) {
    pthread_join(th[i], NULL);
    sum.hits += tal[i].hits;
    sum.tsum += tal[i].tsum;
  }
  return sum;
}

int main(int argc, char **argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: %s FILE LABEL [THREADS=2] [REPEATS=7]\n", argv[0]);
    return 2;
  }
  int threads = argc > 3 ? atoi(argv[3]) : 2;
  int repeats = argc > 4 ? atoi(argv[4]) : 7;
  if (threads < 1 || threads > 256 || repeats < 1 || repeats > 1000) { fprintf(stderr, "bad THREADS/REPEATS\n"); return 2; }
  read_file(argv[1]);
  set_ftz_daz();
  char cfg[64];
  snprintf(cfg, sizeof cfg, "threads=%d", threads);
  RTCDevice dev = rtcNewDevice(cfg);
  if (!dev) { fprintf(stderr, "rtcNewDevice failed\n"); return 1; }
  rtcSetDeviceErrorFunction(dev, on_error, NULL);

  int builds = repeats < 5 ? repeats : 5;
  double bt[5];
  for (int b = 0; b < builds; b++) {
    if (g_scene) rtcReleaseScene(g_scene);
    double t0 = now();
    g_scene = build(dev);
    bt[b] = now() - t0;
  }
  Tally first = trace_all(threads); /* warm-up, and the checksum */
  double *rate = malloc(sizeof(double) * repeats);
  double *cpu_rate = malloc(sizeof(double) * repeats);
  for (int r = 0; r < repeats; r++) {
    double c0 = cpu_now(), t0 = now();
    Tally t = trace_all(threads);
    rate[r] = g_nrays / (now() - t0) / 1e6;
    cpu_rate[r] = g_nrays / fmax(cpu_now() - c0, 1e-3) / 1e6;
    if (t.hits != first.hits) { fprintf(stderr, "hit count changed between runs\n"); return 1; }
  }
  double mn = rate[0], mx = rate[0];
  for (int r = 1; r < repeats; r++) { mn = fmin(mn, rate[r]); mx = fmax(mx, rate[r]); }
  printf("RESULT embree %s tris=%u rays=%u build_ms=%.3f mrays_s=%.3f min=%.3f max=%.3f cpu_mrays_s=%.3f hits=%zu tsum=%.6f threads=%d repeats=%d\n",
         argv[2], g_ntris, g_nrays, 1e3 * median(bt, builds), median(rate, repeats), mn, mx, median(cpu_rate, repeats), first.hits, first.tsum,
         threads, repeats);
  rtcReleaseScene(g_scene);
  rtcReleaseDevice(dev);
  return 0;
}

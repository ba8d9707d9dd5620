/* The Embree peer of `cargo xtask bench --only rays --peer embree` (dev-only; built by xtask
 * against Debian's libembree-dev when it is installed, never part of pcgi).
 *
 * Usage: embree_rays DIR THREADS
 *
 * Reads what `pc-raybench --dump DIR` wrote, all little-endian f32:
 *   disks.f32       per splat: x y z r nx ny nz clipped
 *   primary.f32     per ray:   ox oy oz t_min dx dy dz t_max
 *   incoherent.f32  the same layout
 *   shadow.f32      the same layout: segments between splats facing each other
 * builds one Embree scene of oriented discs (RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT, the disk
 * primitive pcgi's splats are; Embree knows no border clip) on THREADS threads, traces each ray
 * set with rtcIntersect1 on THREADS threads (a shared counter hands out chunks of 4096 rays, as
 * rayon splits pcgi's), and writes
 *   primary.embree, incoherent.embree   per ray: hit distance (+inf for a miss), primID as f32 bits
 *   shadow.embree   per ray: 1 where rtcOccluded1 finds the segment blocked, else 0
 * and one JSON line on stdout: build seconds and rays per second of each set (after a warm-up
 * pass over the first 10,000 rays, as pc-raybench does). */
#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

static float *read_all(const char *dir, const char *name, size_t *count) {
  char path[4096];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  FILE *f = fopen(path, "rb");
  if (!f) { fprintf(stderr, "embree_rays: %s: cannot open\n", path); exit(2); }
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  float *v = malloc(n);
  if (!v || fread(v, 1, n, f) != (size_t)n) { fprintf(stderr, "embree_rays: %s: short read\n", path); exit(2); }
  fclose(f);
  *count = n / sizeof(float);
  return v;
}

static void write_all(const char *dir, const char *name, const float *v, size_t n) {
  char path[4096];
  snprintf(path, sizeof path, "%s/%s", dir, name);
  FILE *f = fopen(path, "wb");
  if (!f || fwrite(v, sizeof(float), n, f) != n || fclose(f) != 0) {
    fprintf(stderr, "embree_rays: %s: cannot write\n", path); exit(2);
  }
}

struct job {
  RTCScene scene;
  const float *rays;
  float *hits;
  int occlusion; /* rtcOccluded1 (one f32 per ray) instead of rtcIntersect1 (two) */
  size_t begin, end;
  atomic_size_t next;
};

#define CHUNK 4096

static void *worker(void *arg) {
  struct job *j = arg;
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  for (;;) {
    size_t a = atomic_fetch_add(&j->next, CHUNK);
    if (a >= j->end) break;
    size_t b = a + CHUNK < j->end ? a + CHUNK : j->end;
    for (size_t i = a; i < b && j->occlusion; i++) {
      const float *r = j->rays + 8 * i;
      struct RTCRay ray;
      ray.org_x = r[0]; ray.org_y = r[1]; ray.org_z = r[2]; ray.tnear = r[3];
      ray.dir_x = r[4]; ray.dir_y = r[5]; ray.dir_z = r[6]; ray.tfar = r[7];
      ray.time = 0.0f; ray.mask = 0xffffffff; ray.id = 0; ray.flags = 0;
      rtcOccluded1(j->scene, &ctx, &ray);
      j->hits[i] = ray.tfar == -INFINITY ? 1.0f : 0.0f;
    }
    for (size_t i = a; i < b && !j->occlusion; i++) {
      const float *r = j->rays + 8 * i;
      struct RTCRayHit rh;
      rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2]; rh.ray.tnear = r[3];
      rh.ray.dir_x = r[4]; rh.ray.dir_y = r[5]; rh.ray.dir_z = r[6]; rh.ray.tfar = r[7];
      rh.ray.time = 0.0f; rh.ray.mask = 0xffffffff; rh.ray.id = 0; rh.ray.flags = 0;
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
      rtcIntersect1(j->scene, &ctx, &rh);
      uint32_t prim = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? 0xffffffffu : rh.hit.primID;
      j->hits[2 * i] = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? INFINITY : rh.ray.tfar;
      memcpy(&j->hits[2 * i + 1], &prim, 4);
    }
  }
  return NULL;
}

/* Trace rays [begin, end) on `threads` threads; seconds taken. */
static double trace(RTCScene scene, const float *rays, float *hits, int occlusion, size_t begin, size_t end, int threads) {
  struct job j = {scene, rays, hits, occlusion, begin, end};
  atomic_init(&j.next, begin);
  pthread_t t[256];
  double t0 = now();
  for (int i = 1; i < threads; i++) pthread_create(&t[i], NULL, worker, &j);
  worker(&j);
  for (int i = 1; i < threads; i++) pthread_join(t[i], NULL);
  return now() - t0;
}

int main(int argc, char **argv) {
  if (argc != 3) { fprintf(stderr, "usage: embree_rays DIR THREADS\n"); return 2; }
  const char *dir = argv[1];
  int threads = atoi(argv[2]);
  if (threads < 1 || threads > 256) { fprintf(stderr, "embree_rays: THREADS must be 1..256\n"); return 2; }
  size_t nd, np, ni, ns;
  float *disks = read_all(dir, "disks.f32", &nd);
  float *primary = read_all(dir, "primary.f32", &np);
  float *incoherent = read_all(dir, "incoherent.f32", &ni);
  float *shadow = read_all(dir, "shadow.f32", &ns);
  nd /= 8; np /= 8; ni /= 8; ns /= 8;

  char cfg[64];
  snprintf(cfg, sizeof cfg, "threads=%d", threads);
  RTCDevice device = rtcNewDevice(cfg);
  if (!device) { fprintf(stderr, "embree_rays: rtcNewDevice failed\n"); return 2; }
  double t0 = now();
  RTCScene scene = rtcNewScene(device);
  RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT);
  float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 16, nd);
  float *n = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_NORMAL, 0, RTC_FORMAT_FLOAT3, 12, nd);
  for (size_t i = 0; i < nd; i++) {
    memcpy(v + 4 * i, disks + 8 * i, 16);
    memcpy(n + 3 * i, disks + 8 * i + 4, 12);
  }
  rtcCommitGeometry(g);
  rtcAttachGeometry(scene, g);
  rtcReleaseGeometry(g);
  double t1 = now();
  rtcCommitScene(scene);
  double build = now() - t1, copy = t1 - t0;
  if (rtcGetDeviceError(device) != RTC_ERROR_NONE) { fprintf(stderr, "embree_rays: scene build failed\n"); return 2; }

  float *hp = malloc(np * 2 * sizeof(float)), *hi = malloc(ni * 2 * sizeof(float)), *hs = malloc(ns * sizeof(float));
  if (!hp || !hi || !hs) { fprintf(stderr, "embree_rays: out of memory\n"); return 2; }
  trace(scene, primary, hp, 0, 0, np < 10000 ? np : 10000, threads);
  double tp = trace(scene, primary, hp, 0, 0, np, threads);
  double tinc = trace(scene, incoherent, hi, 0, 0, ni, threads);
  double tsh = trace(scene, shadow, hs, 1, 0, ns, threads);
  write_all(dir, "primary.embree", hp, 2 * np);
  write_all(dir, "incoherent.embree", hi, 2 * ni);
  write_all(dir, "shadow.embree", hs, ns);
  printf("{\"peer\": \"Embree %d.%d.%d\", \"threads\": %d, \"disks\": %zu, \"build_s\": %.4f, \"copy_s\": %.4f, "
         "\"primary_rays_per_s\": %.0f, \"incoherent_rays_per_s\": %.0f, \"shadow_rays_per_s\": %.0f}\n",
         RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH, threads, nd, build, copy,
         np / tp, ni / tinc, ns / tsh);
  rtcReleaseScene(scene);
  rtcReleaseDevice(device);
  return 0;
}

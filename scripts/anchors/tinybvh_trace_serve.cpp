// tinybvh's BVH8_CPU traversal (the anchor's trace) over rays bvhlab sends, one pass per request, for
// bvhlab's paired trace benchmark (bench_trace --tinybvh-serve): the scene is loaded and its BVH8_CPU
// built once (as ../shared/tools/tinybvh_anchor.cpp does: BVH8_CPU::Build), then it reads requests from
// stdin:
//   rays PATH   loads rays from PATH (per ray 6 little-endian f32: origin xyz, direction xyz; the
//               anchor's infinite tfar), answers "ok COUNT";
//   trace       one pass over the loaded rays (each traced from a fresh copy, the copy untimed, as in the
//               anchor), answers "SECONDS HIT_FRACTION".
// So tinybvh traces the very rays bvhlab traces, right before or after bvhlab's own pass, instead of
// its own rays of the same kind in a process minutes away.
// The loader and the build are ../shared/tools/tinybvh_anchor.cpp's (included with its main renamed):
//   g++ -O3 -march=x86-64-v3 -std=c++17 -DNO_THREADED_BUILDS -I DIR_WITH_ANCHOR_AND_HEADER this.cpp
#define main tinybvh_anchor_main
#include "tinybvh_anchor.cpp"
#undef main

int main(int argc, char** argv) {
  if (argc < 2) { fprintf(stderr, "usage: %s FILE.obj[.gz]  (then requests on stdin)\n", argv[0]); return 2; }
  std::vector<bvhvec4> tri;
  if (!load_obj(argv[1], tri)) { fprintf(stderr, "cannot read %s\n", argv[1]); return 1; }
  uint32_t n = (uint32_t)(tri.size() / 3);
  BVH8_CPU b8;
  b8.Build(tri.data(), n);
  printf("ready %u\n", n);
  fflush(stdout);
  std::vector<Ray> rays;
  char line[4096];
  while (fgets(line, sizeof line, stdin)) {
    std::string req(line);
    while (!req.empty() && (req.back() == '\n' || req.back() == '\r')) req.pop_back();
    if (req.rfind("rays ", 0) == 0) {
      FILE* f = fopen(req.c_str() + 5, "rb");
      rays.clear();
      float v[6];
      while (f && fread(v, sizeof(float), 6, f) == 6) rays.push_back(Ray(bvhvec3(v[0], v[1], v[2]), bvhvec3(v[3], v[4], v[5])));
      if (f) fclose(f);
      printf("ok %zu\n", rays.size());
    } else if (req == "trace") {
      std::vector<Ray> rs = rays;
      size_t hits = 0;
      auto t0 = std::chrono::steady_clock::now();
      for (auto& r : rs) { b8.Intersect(r); if (r.hit.t < BVH_FAR) hits++; }
      auto t1 = std::chrono::steady_clock::now();
      printf("%.6f %.6f\n", std::chrono::duration<double>(t1 - t0).count(), rays.empty() ? 0.0 : (double)hits / rays.size());
    } else {
      printf("error unknown request\n");
    }
    fflush(stdout);
  }
  return 0;
}

// tinybvh's BuildAVX on one thread, one build per request, for bvhlab's paired build benchmark
// (scripts/bench-binned.sh, build_bench with BUILD_BENCH_PAIR): the scene is loaded once, then every
// line read from stdin runs one BuildAVX and answers "MS SAH" (the build's milliseconds, its SAH cost
// by the anchor's formula). build_bench alternates its own builds with these, so both sides of a pair
// run milliseconds apart instead of in processes seconds or minutes apart.
// The loader, the SAH formula and the build are ../shared/tools/tinybvh_anchor.cpp's (included here with
// its main renamed), compiled like its single-thread copy:
//   g++ -O3 -march=x86-64-v3 -std=c++17 -DNO_THREADED_BUILDS -I DIR_WITH_ANCHOR_AND_HEADER this.cpp
#define main tinybvh_anchor_main
#include "tinybvh_anchor.cpp"
#undef main

int main(int argc, char** argv) {
  if (argc < 2) { fprintf(stderr, "usage: %s FILE.obj[.gz]  (then one line per build on stdin)\n", argv[0]); return 2; }
  std::vector<bvhvec4> tri;
  if (!load_obj(argv[1], tri)) { fprintf(stderr, "cannot read %s\n", argv[1]); return 1; }
  uint32_t n = (uint32_t)(tri.size() / 3);
  printf("ready %u\n", n);
  fflush(stdout);
  char line[256];
  while (fgets(line, sizeof line, stdin)) {
    BVH b;
    auto t0 = std::chrono::steady_clock::now();
    b.BuildAVX(tri.data(), n);
    auto t1 = std::chrono::steady_clock::now();
    size_t ni = 0, nl = 0;
    double cost = sah(b, ni, nl);
    printf("%.4f %.4f\n", std::chrono::duration<double, std::milli>(t1 - t0).count(), cost);
    fflush(stdout);
  }
  return 0;
}

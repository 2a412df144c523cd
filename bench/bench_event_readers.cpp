// Read speed of every event reader, side by side in one run: the same synthetic stream (default
// 2,000,000 events at 1280x720) written in each format, then read with read_events (best of 3),
// printed as Mev/s and as a ratio to the text reader. The real samples are timed too when present.
// usage: vkunroll-bench-event-readers [EVENTS] [SHARED_DIR]
#include <zip.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "vkunroll/host/events/event_reader.hpp"
#include "../tests/event_test_encoders.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;

namespace {

void write_bytes(const std::string& path, const std::vector<uint8_t>& b) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}

void write_npz(const std::string& path, const std::vector<uint8_t>& npy, bool deflate) {
  int err = 0;
  zip_t* z = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
  zip_source_t* s = zip_source_buffer(z, npy.data(), npy.size(), 0);
  const zip_int64_t i = zip_file_add(z, "event.npy", s, ZIP_FL_OVERWRITE);
  zip_set_file_compression(z, zip_uint64_t(i), deflate ? ZIP_CM_DEFLATE : ZIP_CM_STORE, 1);
  zip_close(z);
}

double time_read(const std::string& path, size_t& n) {
  double best = 1e30;
  for (int rep = 0; rep < 3; ++rep) {
    const auto t0 = std::chrono::steady_clock::now();
    const EventStream ev = read_events(path);
    best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    n = ev.size();
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  const size_t n = argc > 1 ? size_t(std::stoull(argv[1])) : 2000000;
  const std::string shared = argc > 2 ? argv[2] : std::string(VKUNROLL_SOURCE_DIR) + "/../shared";
  const fs::path dir = fs::temp_directory_path() / ("vkunroll_bench_readers_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const EventStream ev = evtest::random_stream(n, 1280, 720, 42, 1000, 3);
  std::vector<std::pair<std::string, std::string>> files;  // label, path
  auto add = [&](const std::string& label, const std::string& name) { files.emplace_back(label, (dir / name).string()); };
  write_events_text((dir / "ev.txt").string(), ev), add("text t x y p", "ev.txt");
  write_events_hdf5((dir / "ev.h5").string(), ev), add("hdf5 events/{t,x,y,p}", "ev.h5");
  const auto npy = evtest::encode_npy_nx4<int64_t>(ev, "<i8");
  write_bytes((dir / "ev.npy").string(), npy), add("npy N x 4 int64", "ev.npy");
  write_npz((dir / "ev_stored.npz").string(), npy, false), add("npz stored", "ev_stored.npz");
  write_npz((dir / "ev_deflate.npz").string(), npy, true), add("npz deflate", "ev_deflate.npz");
  write_bytes((dir / "ev2.raw").string(), evtest::encode_evt2(ev, "% evt 2.0\n% geometry 1280x720\n")), add("EVT 2.0 .raw", "ev2.raw");
  write_bytes((dir / "ev3.raw").string(), evtest::encode_evt3(ev, "% evt 3.0\n% geometry 1280x720\n", true)), add("EVT 3.0 .raw", "ev3.raw");
  write_bytes((dir / "ev.dat").string(), evtest::encode_dat(ev)), add("Prophesee .dat", "ev.dat");
  write_bytes((dir / "lz4.aedat4").string(), evtest::encode_aedat4(ev, 1, 5000)), add("AEDAT 4 LZ4", "lz4.aedat4");
  write_bytes((dir / "zstd.aedat4").string(), evtest::encode_aedat4(ev, 3, 5000)), add("AEDAT 4 zstd", "zstd.aedat4");

  std::printf("event reader speed, %zu synthetic events at 1280x720 (best of 3 reads each)\n", n);
  std::printf("%-24s %12s %10s %10s %12s\n", "format", "file MiB", "seconds", "Mev/s", "x text");
  double text_rate = 0;
  for (const auto& [label, path] : files) {
    size_t got = 0;
    const double s = time_read(path, got);
    if (got != n) {
      std::fprintf(stderr, "%s: read %zu events, expected %zu\n", label.c_str(), got, n);
      return 1;
    }
    const double rate = double(n) / s * 1e-6;
    if (text_rate == 0) text_rate = rate;
    std::printf("%-24s %12.1f %10.3f %10.2f %12.2f\n", label.c_str(), double(fs::file_size(path)) / (1 << 20), s, rate,
                rate / text_rate);
  }
  for (const char* real : {"data/real-events/evt3_sample.raw", "data/real-events/sample.aedat4"}) {
    const fs::path p = fs::path(shared) / real;
    if (!fs::exists(p)) {
      std::printf("%-24s absent (%s)\n", real, p.c_str());
      continue;
    }
    size_t got = 0;
    const double s = time_read(p.string(), got);
    std::printf("%-24s %12.1f %10.4f %10.2f %12.2f   (%zu events)\n", p.filename().c_str(),
                double(fs::file_size(p)) / (1 << 20), s, double(got) / s * 1e-6, double(got) / s * 1e-6 / text_rate, got);
  }
  fs::remove_all(dir);
  return 0;
}

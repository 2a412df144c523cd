// Read speed of every event reader, side by side in one run: the same synthetic stream (default
// 2,000,000 events at 1280x720) written in each format, then read with read_events (best of 3),
// printed as Mev/s and as a ratio to the text reader. The real samples (tests/data/real/) are timed too.
// usage: vkunroll-bench-event-readers [EVENTS] [REAL_DIR]   (REAL_DIR: default tests/data/real)
//
// `windows` mode: a 200-frame sequence read window by window (frame k: [k P, k P + 1.5 P), as
// `vkunroll unroll` reads overlapping frame windows), per format: one full scan; 200 one-off
// windowed read_events calls (each scans from the start: the behaviour before the index); 200 reads
// through one EventFileReader (indexed). Also compiles against a tree without EventFileReader
// (then only the one-off column), so the same file measures the code before the change.
// usage: vkunroll-bench-event-readers windows [EVENTS] [FRAMES]
#include <zip.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "bench_args.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#if __has_include("vkunroll/host/events/event_file_reader.hpp")
#include "vkunroll/host/events/event_file_reader.hpp"
#define VKUNROLL_HAVE_FILE_READER 1
#endif
#include "../tests/event_test_encoders.hpp"
#if __has_include("vkunroll/host/events/rosbag_detail.hpp")
#include "../tests/rosbag_test_encoder.hpp"
#define VKUNROLL_HAVE_ROSBAG 1
#endif
#include "../tests/event_test_encoders_jaer.hpp"

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
    const Stopwatch reading;
    const EventStream ev = read_events(path);
    best = std::min(best, reading.seconds());
    n = ev.size();
  }
  return best;
}

// Writes `ev` in every format into `dir`: (label, path).
std::vector<std::pair<std::string, std::string>> write_all(const fs::path& dir, const EventStream& ev) {
  std::vector<std::pair<std::string, std::string>> files;
  auto add = [&](const std::string& label, const std::string& name) { files.emplace_back(label, (dir / name).string()); };
  const std::string geometry = "% geometry " + std::to_string(ev.width) + "x" + std::to_string(ev.height) + "\n";
  write_events_text((dir / "ev.txt").string(), ev), add("text t x y p", "ev.txt");
  write_events_hdf5((dir / "ev.h5").string(), ev), add("hdf5 events/{t,x,y,p}", "ev.h5");
  const auto npy = evtest::encode_npy_nx4<int64_t>(ev, "<i8");
  write_bytes((dir / "ev.npy").string(), npy), add("npy N x 4 int64", "ev.npy");
  write_npz((dir / "ev_stored.npz").string(), npy, false), add("npz stored", "ev_stored.npz");
  write_npz((dir / "ev_deflate.npz").string(), npy, true), add("npz deflate", "ev_deflate.npz");
  write_bytes((dir / "ev2.raw").string(), evtest::encode_evt2(ev, "% evt 2.0\n" + geometry)), add("EVT 2.0 .raw", "ev2.raw");
  write_bytes((dir / "ev3.raw").string(), evtest::encode_evt3(ev, "% evt 3.0\n" + geometry, true)), add("EVT 3.0 .raw", "ev3.raw");
  write_bytes((dir / "ev.dat").string(), evtest::encode_dat(ev)), add("Prophesee .dat", "ev.dat");
  write_bytes((dir / "lz4.aedat4").string(), evtest::encode_aedat4(ev, 1, 5000)), add("AEDAT 4 LZ4", "lz4.aedat4");
  write_bytes((dir / "zstd.aedat4").string(), evtest::encode_aedat4(ev, 3, 5000)), add("AEDAT 4 zstd", "zstd.aedat4");
#ifdef VKUNROLL_HAVE_ROSBAG
  // ROS bags: 1000 events a message, 50 messages a chunk (near rosbag's 768 KiB chunks).
  evtest::BagOptions bo;
  bo.events_per_message = 1000, bo.messages_per_chunk = 50;
  write_bytes((dir / "dvs.bag").string(), evtest::encode_rosbag(ev, bo)), add("bag dvs_msgs", "dvs.bag");
  bo.compression = "lz4";
  write_bytes((dir / "dvs_lz4.bag").string(), evtest::encode_rosbag(ev, bo)), add("bag dvs_msgs lz4", "dvs_lz4.bag");
  bo.compression = "bz2";
  write_bytes((dir / "dvs_bz2.bag").string(), evtest::encode_rosbag(ev, bo)), add("bag dvs_msgs bz2", "dvs_bz2.bag");
  bo.kind = evtest::BagMessage::evt3_packet, bo.compression = "lz4";
  write_bytes((dir / "evt3.bag").string(), evtest::encode_rosbag(ev, bo)), add("bag EventPacket evt3 lz4", "evt3.bag");
#endif
  write_bytes((dir / "ev21.raw").string(), evtest::encode_evt21(ev, "% evt 2.1\n" + geometry, false)),
      add("EVT 2.1 .raw", "ev21.raw");
  write_bytes((dir / "ev3.aedat").string(), evtest::encode_aedat3(ev, "1280x720 test sensor", 4096, false)),
      add("AEDAT 3.1", "ev3.aedat");
  // AEDAT 2.0's DAVIS addresses hold x < 1024, y < 512: the same times and count on a DAVIS346.
  EventStream davis = ev;
  davis.width = 346, davis.height = 260;
  for (size_t i = 0; i < davis.size(); ++i) davis.x[i] = uint16_t(davis.x[i] % 346), davis.y[i] = uint16_t(davis.y[i] % 260);
  write_bytes((dir / "ev2.aedat").string(), evtest::encode_aedat2(davis, "# AEChip: Davis346B\r\n", false)),
      add("AEDAT 2.0 (346x260)", "ev2.aedat");
  return files;
}

// The windows mode (see the top of the file).
int run_windows(size_t n, int frames) {
  const fs::path dir = fs::temp_directory_path() / ("vkunroll_bench_windows_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const EventStream ev = evtest::random_stream(n, 346, 260, 42, 1000, 3);
  const auto files = write_all(dir, ev);
  const int64_t first = ev.t.front(), period = (ev.t.back() - first) / frames + 1;
  std::printf("%d frame windows [k P, k P + 1.5 P) over %zu synthetic events at 346x260 (P = %lld us)\n", frames, n,
              static_cast<long long>(period));
  std::printf("%-22s %8s %9s %11s %9s %11s %9s %9s %11s %9s\n", "format", "MiB", "full s", "one-off s", "/full",
              "indexed s", "/full", "1 win ms", "idx/1 win", "speedup");
  for (const auto& [label, path] : files) {
    Stopwatch t0;
    const size_t total = read_events(path).size();
    const double full = t0.seconds();
    size_t got_old = 0, got_new = 0;
    (void)got_new;
    t0.restart();
    for (int k = 0; k < frames; ++k) {
      EventReadOptions o;
      o.t_begin_us = first + k * period;
      o.t_end_us = first + k * period + period * 3 / 2;
      got_old += read_events(path, o).size();
    }
    const double old_s = t0.seconds();
    double new_s = 0, one_ms = 0;
#ifdef VKUNROLL_HAVE_FILE_READER
    t0.restart();
    EventFileReader reader(path, {});
    for (int k = 0; k < frames; ++k) got_new += reader.read(first + k * period, first + k * period + period * 3 / 2).size();
    new_s = t0.seconds();
    // One frame's window once the file is indexed (median of 21 frames spread over the recording).
    std::vector<double> one;
    for (int k = 0; k < frames; k += std::max(1, frames / 21)) {
      t0.restart();
      reader.read(first + k * period, first + k * period + period * 3 / 2);
      one.push_back(t0.ms());
    }
    std::nth_element(one.begin(), one.begin() + long(one.size() / 2), one.end());
    one_ms = one[one.size() / 2];
    if (got_new != got_old) {
      std::fprintf(stderr, "%s: indexed reads gave %zu events, one-off reads %zu\n", label.c_str(), got_new, got_old);
      return 1;
    }
#endif
    std::printf("%-22s %8.1f %9.3f %11.3f %9.1f %11.3f %9.2f %9.3f %11.0f %9.1f\n", label.c_str(),
                double(fs::file_size(path)) / (1 << 20), full, old_s, old_s / full, new_s, new_s / full, one_ms,
                one_ms > 0 ? new_s * 1e3 / one_ms : 0.0, new_s > 0 ? old_s / new_s : 0.0);
    (void)total;
    std::fflush(stdout);
  }
  fs::remove_all(dir);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "windows")
    return run_windows(argc > 2 ? size_t(bench_int_arg("vkunroll-bench-event-readers", "events", argv[2], 1, 1LL << 34)) : 1000000,
                       argc > 3 ? static_cast<int>(bench_int_arg("vkunroll-bench-event-readers", "windows", argv[3], 1, 1000000)) : 200);
  const size_t n = argc > 1 ? size_t(bench_int_arg("vkunroll-bench-event-readers", "events", argv[1], 1, 1LL << 34)) : 2000000;
  const std::string real_dir = argc > 2 ? argv[2] : std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/real";
  const fs::path dir = fs::temp_directory_path() / ("vkunroll_bench_readers_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const EventStream ev = evtest::random_stream(n, 1280, 720, 42, 1000, 3);
  const auto files = write_all(dir, ev);

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
  for (const char* real : {"evt3_sample.raw", "sample.aedat4"}) {
    const fs::path p = fs::path(real_dir) / real;
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

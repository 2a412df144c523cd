// Writes the fuzzers' seed corpus: small valid files of every format (from the test encoders),
// a few deliberately odd ones, and the first bytes of the real samples when present.
// usage: fuzz_make_seeds OUT_DIR [SHARED_DIR]   (OUT_DIR/<reader>/seed_*)
#include <zip.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>

#include "event_test_encoders.hpp"
#include "rosbag_test_encoder.hpp"
#include "event_test_encoders_jaer.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

void put(const fs::path& dir, const std::string& name, const std::vector<uint8_t>& b) {
  fs::create_directories(dir);
  std::ofstream f(dir / name, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}

std::vector<uint8_t> head(const fs::path& p, size_t n) {
  std::ifstream f(p, std::ios::binary);
  std::vector<uint8_t> b(n);
  f.read(reinterpret_cast<char*>(b.data()), std::streamsize(n));
  b.resize(size_t(f.gcount()));
  return b;
}

std::vector<uint8_t> make_zip(const std::vector<std::pair<std::string, std::vector<uint8_t>>>& members, bool deflate,
                              const fs::path& tmp) {
  int err = 0;
  zip_t* z = zip_open(tmp.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
  for (const auto& [name, bytes] : members) {
    zip_source_t* s = zip_source_buffer(z, bytes.data(), bytes.size(), 0);
    const zip_int64_t idx = zip_file_add(z, name.c_str(), s, ZIP_FL_OVERWRITE);
    zip_set_file_compression(z, zip_uint64_t(idx), deflate ? ZIP_CM_DEFLATE : ZIP_CM_STORE, 0);
  }
  zip_close(z);
  auto b = head(tmp, 1 << 20);
  fs::remove(tmp);
  return b;
}

// The events of a real recording's first bytes (EVT 3.0; drop: the cut last word is dropped).
EventStream first_events(const std::vector<uint8_t>& raw) {
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  detail::MemorySource src("head.raw", raw.data(), raw.size());
  detail::EventSink sink("head.raw", o, rep);
  detail::read_evt3(src, sink);
  return sink.finish();
}

// The index fuzzer (fuzz_index.hpp's index_case): first byte = format (text, evt2, evt3, dat,
// aedat4) + 5 * policy (error, drop, sort); files past the 32 KiB checkpoint stride, with records out of time order.
void put_index_seeds(const fs::path& out) {
  EventStream many = random_stream(9000, 64, 48, 4, 1000, 5);
  for (size_t i = 0; i < many.size(); i += 37) many.t[i] -= 3;
  std::string txt = "# width 64 height 48\n";
  for (size_t i = 0; i < many.size() / 2; ++i)
    txt += std::to_string(many.t[i]) + " " + std::to_string(many.x[i]) + " " + std::to_string(many.y[i]) + " 1\n";
  const std::vector<std::vector<uint8_t>> bodies = {
      text_bytes(txt), encode_evt2(many, "% evt 2.0\n% geometry 64x48\n"),
      encode_evt3(many, "% evt 3.0\n% geometry 64x48\n", true), encode_dat(many), encode_aedat4(many, 1, 700)};
  for (int f = 0; f < 5; ++f)
    for (int policy = 0; policy < 3; policy += (f == 2 ? 1 : 2)) {
      std::vector<uint8_t> b{uint8_t(f + 5 * policy)};
      b.insert(b.end(), bodies[size_t(f)].begin(), bodies[size_t(f)].end());
      put(out / "index", "seed_" + std::to_string(f) + "_" + std::to_string(policy), b);
    }
  // EVT 2.1, AEDAT 2.0, AEDAT 3.1: first byte 15 + format + 3 * policy (fuzz_index.hpp).
  EventStream davis = many;
  davis.width = 346, davis.height = 260;
  const std::vector<std::vector<uint8_t>> jaer = {encode_evt21(many, "% evt 2.1\n% geometry 64x48\n", false),
                                                  encode_aedat2(davis, "# AEChip: Davis346B\r\n", true),
                                                  encode_aedat3(many, "DAVIS346B", 300, true)};
  for (int f = 0; f < 3; ++f)
    for (int policy = 0; policy < 3; ++policy) {
      std::vector<uint8_t> b{uint8_t(15 + f + 3 * policy)};
      b.insert(b.end(), jaer[size_t(f)].begin(), jaer[size_t(f)].end());
      put(out / "index", "seed_jaer_" + std::to_string(f) + "_" + std::to_string(policy), b);
    }
  // ROS bags (chunks of 4 messages of 50 events, lz4): first byte 24 + policy.
  BagOptions bo;
  bo.events_per_message = 50, bo.compression = "lz4";
  const std::vector<uint8_t> bag = encode_rosbag(many, bo);
  for (int policy = 0; policy < 3; ++policy) {
    std::vector<uint8_t> b{uint8_t(24 + policy)};
    b.insert(b.end(), bag.begin(), bag.end());
    put(out / "index", "seed_bag_" + std::to_string(policy), b);
  }
}

// Seeds cut from the real recordings of the shared folder, where they exist.
void put_real_seeds(const fs::path& out, const fs::path& shared) {
  if (fs::exists(shared / "data/real-events/evt3_sample.raw"))
    put(out / "evt3", "seed_real_head", head(shared / "data/real-events/evt3_sample.raw", 4096));
  if (fs::exists(shared / "data/real-events/evt3_sample.raw")) {
    // The real recording's first events, re-encoded as EVT 2.1 and AEDAT 3.1.
    const auto raw = head(shared / "data/real-events/evt3_sample.raw", 4096);
    const EventStream real = first_events(raw);
    put(out / "evt21", "seed_real_head", encode_evt21(real, "% evt 2.1\n% format EVT21;height=720;width=1280\n", false));
    put(out / "aedat3", "seed_real_head", encode_aedat3(real, "Prophesee", 64, false));
  }
  if (fs::exists(shared / "data/real-events/sample.aedat4"))
    put(out / "aedat4", "seed_real_head", head(shared / "data/real-events/sample.aedat4", 2334 + 8 + 7949 + 8 + 383));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: fuzz_make_seeds OUT_DIR [SHARED_DIR]\n";
    return 2;
  }
  const fs::path out = argv[1];
  const EventStream ev = random_stream(40, 64, 48, 1);
  const EventStream big = random_stream(300, 1280, 720, 2, (int64_t(1) << 24) - 500);

  put(out / "evt2", "seed_small", encode_evt2(ev, "% evt 2.0\n% format EVT2;height=48;width=64\n% end\n"));
  put(out / "evt2", "seed_plugin", encode_evt2(big, "% plugin_name hal_plugin_gen31_fx3\n"));
  put(out / "evt3", "seed_small", encode_evt3(ev, "% evt 3.0\n% format EVT3;height=48;width=64\n% end\n", false));
  put(out / "evt3", "seed_vectors_wrap", encode_evt3(big, "% evt 3.0\n% plugin_name hal_plugin_gen41_evk3\n", true));
  put(out / "dat", "seed_small", encode_dat(ev));
  put(out / "dat", "seed_big", encode_dat(big));
  put(out / "aedat4", "seed_none", encode_aedat4(ev, 0, 16));
  put(out / "aedat4", "seed_lz4", encode_aedat4(ev, 1, 16));
  put(out / "aedat4", "seed_zstd_notable", encode_aedat4(ev, 3, 16, false));
  put(out / "evt21", "seed_small", encode_evt21(ev, "% evt 2.1\n% format EVT21;height=48;width=64\n% end\n", false));
  put(out / "evt21", "seed_legacy_wrap",
      encode_evt21(big, "% format EVT21;endianness=legacy;height=720;width=1280\n", true));
  put(out / "aedat2", "seed_davis346", encode_aedat2(random_stream(120, 346, 260, 5), "# AEChip: Davis346B\r\n", true));
  put(out / "aedat2", "seed_no_end_line",
      encode_aedat2(random_stream(40, 240, 180, 6), "# AEChip: DAVIS240C\r\n", false, nullptr, false));
  put(out / "aedat3", "seed_dvs128", encode_aedat3(ev, "DVS128", 16, true));
  put(out / "aedat3", "seed_davis346_overflow",
      encode_aedat3(random_stream(60, 346, 260, 7, (int64_t(1) << 31) - 30), "DAVIS346B", 25, false));
  put(out / "npy", "seed_i8", encode_npy_nx4<int64_t>(ev, "<i8"));
  put(out / "npy", "seed_f4_fortran", encode_npy_nx4<float>(ev, "<f4", true, true));
  put(out / "npy", "seed_record", encode_npy_record(ev));
  put(out / "npy", "seed_be", encode_npy_nx4<int16_t>(ev, ">i2"));
  const fs::path tmpzip = out / "tmp.zip";
  put(out / "npz", "seed_stored", make_zip({{"event.npy", encode_npy_nx4<int32_t>(ev, "<i4")}}, false, tmpzip));
  put(out / "npz", "seed_deflate_record", make_zip({{"event.npy", encode_npy_record(ev)}}, true, tmpzip));
  {
    std::vector<std::pair<std::string, std::vector<uint8_t>>> sep;
    auto col = [&](const char* name, auto get) {
      std::vector<uint8_t> d;
      for (size_t i = 0; i < ev.size(); ++i) put32(d, uint32_t(get(i)));
      sep.emplace_back(std::string(name) + ".npy",
                       encode_npy("{'descr': '<i4', 'fortran_order': False, 'shape': (" + std::to_string(ev.size()) + ",), }", d));
    };
    col("x", [&](size_t i) { return ev.x[i]; });
    col("y", [&](size_t i) { return ev.y[i]; });
    col("p", [&](size_t i) { return ev.p[i] > 0 ? 1 : 0; });
    col("t", [&](size_t i) { return ev.t[i]; });
    put(out / "npz", "seed_separate", make_zip(sep, true, tmpzip));
  }
  put(out / "text", "seed_txyp", text_bytes("# width 64 height 48\n1 2 3 1\n5 6 7 0\n5 8 9 -1\n"));
  put(out / "text", "seed_e2vid", text_bytes("240 180\n0.000001 1 2 1\n0.000123456 3 4 0\n"));
  put(out / "text", "seed_csv", text_bytes("x,y,timestamp,polarity\n1,2,1.5,True\n3,4,2e3,False\nnan,1,1,1\n"));
  {
    BagOptions bo;
    bo.events_per_message = 7;
    put(out / "rosbag", "seed_dvs", encode_rosbag(ev, bo));
    bo.kind = BagMessage::evt3_packet, bo.compression = "lz4";
    put(out / "rosbag", "seed_evt3_lz4", encode_rosbag(ev, bo));
    bo.kind = BagMessage::mono_packet, bo.compression = "bz2", bo.index = false;
    put(out / "rosbag", "seed_mono_bz2_noindex", encode_rosbag(ev, bo));
  }
  std::mt19937 rng(3);
  for (int k = 0; k < 4; ++k) {
    std::vector<uint8_t> r(size_t(200 + 200 * k));
    for (auto& b : r) b = uint8_t(rng());
    put(out / "hdf5", "seed_random_" + std::to_string(k), r);
  }
  put_index_seeds(out);
  if (argc > 2) put_real_seeds(out, argv[2]);
  std::cout << "seeds written under " << out << "\n";
  return 0;
}

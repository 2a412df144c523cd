// The sequence loader's fuzz harness (fuzz/fuzz_sequence.hpp) over every committed seed and
// finding in tests/fuzz_corpus/sequence/, the way fuzz_sequence runs them: every input either
// loads or throws vkunroll::Error. The simulator's seeds must load (they are valid sequences).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <unistd.h>

#include "../fuzz/fuzz_sequence.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;

namespace {

std::string bytes_of(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

const uint8_t* u8(const std::string& s) { return reinterpret_cast<const uint8_t*>(s.data()); }

}  // namespace

TEST(SequenceFuzzCorpus, EveryCorpusFileLoadsOrIsAnError) {
  const fs::path corpus = fs::path(VKUNROLL_SOURCE_DIR) / "tests" / "fuzz_corpus" / "sequence";
  const fs::path dir = fs::temp_directory_path() / ("vkunroll_sequence_corpus_" + std::to_string(::getpid()));
  int files = 0, seeds_loaded = 0;
  for (const auto& e : fs::directory_iterator(corpus)) {
    const std::string blob = bytes_of(e.path());
    fuzz::write_sequence_folder(dir, u8(blob), blob.size());
    EXPECT_TRUE(fuzz::sequence_load_survives(dir, u8(blob), blob.size())) << e.path();
    ++files;
    if (e.path().filename().string().rfind("seed_", 0) == 0) {
      SequenceOptions o;
      o.check_frame_sizes = !(blob.back() & 2);
      o.events.on_bad = (blob.back() & 4) ? BadEventPolicy::sort : BadEventPolicy::drop;
      const Sequence s = load_sequence(dir.string(), o);  // throws (fails) if a seed is not a valid sequence
      EXPECT_EQ(s.frames.size(), 2u) << e.path();
      EXPECT_EQ(s.width, 8) << e.path();
      EXPECT_GT(s.read_events(INT64_MIN, INT64_MAX).size(), 0u) << e.path();
      ++seeds_loaded;
    }
  }
  fs::remove_all(dir);
  EXPECT_GE(files, 8);
  EXPECT_GE(seeds_loaded, 8);
}

TEST(SequenceFuzzCorpus, BlobNamesStayInsideTheFolder) {
  EXPECT_EQ(fuzz::safe_member_name("../../etc/passwd"), "etc/passwd");
  EXPECT_EQ(fuzz::safe_member_name("/abs/a/b/c"), "abs/a");
  EXPECT_EQ(fuzz::safe_member_name("rs/0 1\x01.png"), "rs/01.png");
  EXPECT_EQ(fuzz::safe_member_name(".."), "");
  const std::string blob = std::string("{}") + "\n@@FILE rs/a.png\nAB" + "\n@@FILE ../x\nC";
  const auto files = fuzz::split_sequence_blob(u8(blob), blob.size());
  ASSERT_EQ(files.size(), 3u);
  EXPECT_EQ(files[0], std::make_pair(std::string("meta.json"), std::string("{}")));
  EXPECT_EQ(files[1], std::make_pair(std::string("rs/a.png"), std::string("AB")));
  EXPECT_EQ(files[2], std::make_pair(std::string("x"), std::string("C")));
}

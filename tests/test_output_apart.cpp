// Never delete what it did not write (issue 28, item 1): an output folder lists what vkunroll wrote
// in its manifest, --overwrite and --resume refuse a folder holding anything else at any depth, and
// no command writes an output that is, holds or lies inside one of its inputs.
#include <gtest/gtest.h>

#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

#include "cli_test_util.hpp"

namespace fs = std::filesystem;
using clitest::cli;
using clitest::CliRun;
using clitest::has;

namespace {

fs::path temp_dir(const std::string& name) { return clitest::temp_dir("apart", name); }

fs::path make_sequence(const fs::path& where) {
  const CliRun r = cli("simulate --out " + where.string() +
                       " --preset clean --size 48x32 --frames 2 --gt-per-frame 1 --events-format txt --quiet");
  EXPECT_EQ(r.rc, 0) << r.out;
  return where;
}

CliRun unroll(const fs::path& seq, const fs::path& out, const std::string& extra = "", const std::string& env = "") {
  return cli("unroll " + seq.string() + " --out " + out.string() + " --mode physics --times 0.5 --quiet --no-video " + extra, env);
}

std::set<std::string> manifest(const fs::path& out) {
  std::set<std::string> files;
  std::ifstream in(out / ".vkunroll-manifest");
  std::string line;
  while (std::getline(in, line))
    if (!line.empty() && line[0] != '#') files.insert(line);
  return files;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST(OutputApart, TheManifestListsWhatARunWroteAndAnOverwriteOfItWorks) {
  const fs::path d = temp_dir("manifest");
  const fs::path seq = make_sequence(d / "seq");
  ASSERT_EQ(unroll(seq, d / "out").rc, 0);
  const std::set<std::string> listed = manifest(d / "out");
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(d / "out"))
    if (e.is_regular_file() && e.path().filename() != ".vkunroll-manifest") {
      ++files;
      EXPECT_TRUE(listed.count(e.path().lexically_relative(d / "out").string())) << e.path();
    }
  EXPECT_EQ(files, listed.size());
  EXPECT_TRUE(listed.count("summary.json"));
  const CliRun r = unroll(seq, d / "out", "--overwrite");
  EXPECT_EQ(r.rc, 0) << r.out;
  // An output from before manifests (its names and frames/*.png only) is replaced as before.
  fs::remove(d / "out" / ".vkunroll-manifest");
  EXPECT_EQ(unroll(seq, d / "out", "--resume").rc, 0);
  fs::remove_all(d);
}

TEST(OutputApart, OverwriteAndResumeRefuseAFolderHoldingAUsersFileAtAnyDepth) {
  const fs::path d = temp_dir("user-file");
  const fs::path seq = make_sequence(d / "seq");
  ASSERT_EQ(unroll(seq, d / "out").rc, 0);
  std::ofstream(d / "out" / "frames" / "notes.txt") << "mine";
  for (const std::string how : {"--overwrite", "--resume"}) {
    const CliRun r = unroll(seq, d / "out", how);
    EXPECT_EQ(r.rc, 2) << how << ": " << r.out;
    EXPECT_TRUE(has(r, "frames/notes.txt") && has(r, "vkunroll did not write there")) << r.out;
    EXPECT_EQ(slurp(d / "out" / "frames" / "notes.txt"), "mine") << how;
  }
  // Without the manifest too (an output from before manifests), and for a folder that holds only
  // a user's frames/notes.txt.
  fs::remove(d / "out" / ".vkunroll-manifest");
  EXPECT_EQ(unroll(seq, d / "out", "--overwrite").rc, 2);
  fs::create_directories(d / "only" / "frames");
  std::ofstream(d / "only" / "frames" / "notes.txt") << "mine";
  const CliRun r = unroll(seq, d / "only", "--overwrite");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_EQ(slurp(d / "only" / "frames" / "notes.txt"), "mine");
  fs::remove_all(d);
}

TEST(OutputApart, NoOutputIsHoldsOrLiesInsideAnInput) {
  const fs::path d = temp_dir("inputs");
  make_sequence(d / "seq");
  ASSERT_EQ(unroll(d / "seq", d / "out").rc, 0);
  // The sequence inside the earlier output: --overwrite would have deleted it.
  fs::rename(d / "seq", d / "out" / "frames" / "myseq");
  const fs::path inside = d / "out" / "frames" / "myseq";
  CliRun r = unroll(inside, d / "out", "--overwrite");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "holds the input SEQUENCE")) << r.out;
  EXPECT_TRUE(fs::exists(inside / "meta.json"));
  // The output inside the sequence, or the sequence itself.
  r = unroll(inside, inside / "gs");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "lies inside the input SEQUENCE")) << r.out;
  r = unroll(inside, inside, "--overwrite");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(fs::exists(inside / "meta.json"));
  // voxelize over the sequence's own event file, or into the sequence folder.
  const std::string events = slurp(inside / "events.txt");
  for (const fs::path& out : {inside / "events.txt", inside / "ev.safetensors"}) {
    r = cli("voxelize " + inside.string() + " --frames 0 --times 0.5 --out " + out.string());
    EXPECT_EQ(r.rc, 2) << out << ": " << r.out;
    EXPECT_TRUE(has(r, "input")) << r.out;
  }
  EXPECT_EQ(slurp(inside / "events.txt"), events);
  // An events file named by --events inside the output.
  fs::create_directories(d / "out2");
  fs::copy_file(inside / "events.txt", d / "out2" / "ev.txt");
  r = unroll(inside, d / "out2", "--overwrite --events " + (d / "out2" / "ev.txt").string());
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "holds the input --events file")) << r.out;
  EXPECT_TRUE(fs::exists(d / "out2" / "ev.txt"));
  fs::remove_all(d);
}

// Inputs that could block (issue 28, item 5): a FIFO given as the events, the model or a frame
// image, or named by meta.json, is refused at once, naming it (it used to block for ever).
TEST(InputKinds, AFifoIsRefusedWhereverAFileIsRead) {
  const fs::path d = temp_dir("fifo");
  const fs::path seq = make_sequence(d / "seq");
  const fs::path fifo = d / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  const std::string t = "timeout 60 ";
  for (const std::string& args : {"unroll " + seq.string() + " --out " + (d / "o1").string() + " --mode physics --events " + fifo.string(),
                                  "unroll " + seq.string() + " --out " + (d / "o2").string() + " --model " + fifo.string(),
                                  "events " + fifo.string()}) {
    const CliRun r = cli(args, t);
    EXPECT_EQ(r.rc, 65) << args << ": " << r.out;
    EXPECT_TRUE(has(r, "is a FIFO")) << r.out;
  }
  fs::rename(seq / "events.txt", seq / "events-real.txt");
  ASSERT_EQ(::mkfifo((seq / "events.txt").c_str(), 0644), 0);
  CliRun r = cli("unroll " + seq.string() + " --out " + (d / "o3").string() + " --mode physics --quiet", t);
  EXPECT_NE(r.rc, 0);
  EXPECT_NE(r.rc, 124) << "timed out: " << r.out;
  EXPECT_TRUE(has(r, "is a FIFO")) << r.out;
  fs::remove_all(d);
}

// simulate and demo write their sequence staged and renamed into place whole: a second run never
// leaves the first one's files beside its own, and replaces a sequence only with --overwrite (demo:
// its own earlier one) and only when it holds nothing vkunroll did not write.
TEST(OutputApart, SimulateAndDemoReplaceASequenceWholeOrRefuse) {
  const fs::path d = temp_dir("simulate");
  const std::string sim = "simulate --out " + (d / "seq").string() + " --preset clean --size 48x32 --gt-per-frame 1 --quiet";
  ASSERT_EQ(cli(sim + " --frames 3").rc, 0);
  EXPECT_TRUE(fs::exists(d / "seq" / "rs" / "000002.png"));
  CliRun r = cli(sim + " --frames 2");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "--overwrite")) << r.out;
  r = cli(sim + " --frames 2 --overwrite");
  EXPECT_EQ(r.rc, 0) << r.out;
  EXPECT_FALSE(fs::exists(d / "seq" / "rs" / "000002.png"));  // the first run's third frame is gone
  EXPECT_FALSE(fs::exists(d / ".seq.partial"));
  std::ofstream(d / "seq" / "rs" / "mine.txt") << "mine";
  r = cli(sim + " --frames 2 --overwrite");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "rs/mine.txt")) << r.out;
  EXPECT_TRUE(fs::exists(d / "seq" / "meta.json"));
  // The demo into its own earlier folder.
  const std::string demo = "demo --out " + (d / "demo").string() + " --physics-only --size 32x24";
  ASSERT_EQ(cli(demo + " --frames 3").rc, 0);
  EXPECT_TRUE(fs::exists(d / "demo" / "sequence" / "rs" / "000002.png"));
  r = cli(demo + " --frames 2");
  EXPECT_EQ(r.rc, 0) << r.out;
  EXPECT_FALSE(fs::exists(d / "demo" / "sequence" / "rs" / "000002.png"));
  fs::remove_all(d);
}

// Values that were read in silence (issue 28): a gamma in meta.json that is not a number (read as
// 1 before), an event file meta.json names that is missing (exit 66, not 65), and a fence timeout
// that is not a number of seconds (atof made it 0).
TEST(InputKinds, BadMetadataAndEnvironmentValuesAreNamed) {
  const fs::path d = temp_dir("meta-values");
  const fs::path seq = make_sequence(d / "seq");
  const std::string meta = slurp(seq / "meta.json");
  auto with_meta = [&](const std::string& from, const std::string& to) {
    std::string m = meta;
    const size_t at = m.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    m.replace(at, from.size(), to);
    std::ofstream(seq / "meta.json") << m;
  };
  with_meta("\"gamma\": 2.2", "\"gamma\": \"2.2\"");
  CliRun r = unroll(seq, d / "o1");
  EXPECT_EQ(r.rc, 65) << r.out;
  EXPECT_TRUE(has(r, "meta.json:source.settings.gamma = \"2.2\": expected number")) << r.out;
  // The schema checks meta.json before any option applies: --gamma does not excuse a wrong type.
  EXPECT_EQ(cli("unroll " + seq.string() + " --out " + (d / "o2").string() + " --mode physics --gamma 2.2 --quiet").rc, 65);
  with_meta("\"events\": \"events.txt\"", "\"events\": \"gone.txt\"");
  r = unroll(seq, d / "o3");
  EXPECT_EQ(r.rc, 66) << r.out;
  EXPECT_TRUE(has(r, "gone.txt' does not exist")) << r.out;
  std::ofstream(seq / "meta.json") << meta;
  r = unroll(seq, d / "o4", "", "VKUNROLL_FENCE_TIMEOUT_S=abc ");
  EXPECT_NE(r.rc, 0) << r.out;
  EXPECT_TRUE(has(r, "VKUNROLL_FENCE_TIMEOUT_S='abc'")) << r.out;
  fs::remove_all(d);
}

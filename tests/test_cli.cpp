// The `vkunroll` command line as a user meets it (issue 18): exit codes, messages that name the
// option or file, fault-safe output folders (full disk, kill -9, re-runs, --overwrite, --resume)
// and what summary.json says about events. Each case runs the built binary on a tiny simulated
// sequence.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "cli_test_util.hpp"
#include "vkunroll/base/stopwatch.hpp"

namespace fs = std::filesystem;
using clitest::cli;
using clitest::CliRun;
using clitest::has;

namespace {

fs::path temp_dir(const std::string& name) { return clitest::temp_dir("cli", name); }

// A clean 64x48 sequence of 3 frames (RS frame k at t0 = 10000 + 50000k us), events in a .txt.
fs::path make_sequence(const fs::path& dir) {
  const CliRun r = cli("simulate --out " + (dir / "seq").string() +
                    " --preset clean --size 64x48 --frames 3 --gt-per-frame 2 --events-format txt --quiet");
  EXPECT_EQ(r.rc, 0) << r.out;
  return dir / "seq";
}

nlohmann::json read_json(const fs::path& p) {
  std::ifstream f(p);
  return nlohmann::json::parse(f);
}

std::vector<std::string> files_in(const fs::path& d) {
  std::vector<std::string> v;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(d, ec)) v.push_back(e.path().filename().string());
  std::sort(v.begin(), v.end());
  return v;
}

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

}  // namespace

// Found: --bins 0 died with SIGFPE (the range check ran after the division); --target-exposure -5
// and --crop 0,0,0,0 were accepted.
TEST(Cli, VoxelizeRefusesZeroBinsNegativeExposureAndEmptyCrop) {
  const fs::path dir = temp_dir("vox");
  const fs::path seq = make_sequence(dir), out = dir / "v.safetensors";
  const std::string base = "voxelize " + seq.string() + " --frames 0 --times 0.5 --out " + out.string();
  for (const std::string cpu : {"", " --cpu"}) {
    const CliRun r = cli(base + " --bins 0" + cpu);
    EXPECT_EQ(r.rc, 2) << r.out;  // usage, not 136 (SIGFPE)
    EXPECT_TRUE(has(r, "--bins")) << r.out;
  }
  CliRun r = cli(base + " --target-exposure -5");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "--target-exposure -5")) << r.out;
  r = cli(base + " --crop 0,0,0,0");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "--crop 0,0,0,0: the width and height must be positive")) << r.out;
  EXPECT_FALSE(fs::exists(out));
  // A device, FIFO or folder as --out is refused: the temporary file would be renamed over it
  // (run as root, --out /dev/full replaced the device by a regular file). A FIFO stands in here.
  const fs::path fifo = dir / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  r = cli("voxelize " + seq.string() + " --frames 0 --times 0.5 --out " + fifo.string());
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "--out " + fifo.string() + ": exists and is not a regular file")) << r.out;
  EXPECT_TRUE(fs::is_fifo(fifo));
  r = cli("voxelize " + seq.string() + " --frames 0 --times 0.5 --out " + dir.string());
  EXPECT_EQ(r.rc, 2) << r.out;
  r = cli(base + " --bins 2");
  EXPECT_EQ(r.rc, 0) << r.out;
  EXPECT_TRUE(fs::exists(out));
  fs::remove_all(dir);
}

// Found: a full disk exited 0 with 0-byte or missing files that summary.json listed. A per-file
// size limit (ulimit -f, in 1 KiB blocks under bash) fails one write: the first frame PNG at 2 KiB,
// only the contact sheet (~360 KB) at 100 KiB. Either way: exit 74 naming the file, and no output.
TEST(Cli, FullDiskExitsNonZeroNamingTheFileAndLeavesNoOutput) {
  const fs::path dir = temp_dir("fsize");
  const fs::path seq = make_sequence(dir);
  for (const auto& [blocks, file] : {std::pair<int, std::string>{2, "frames/"}, {100, "contact_sheet.png"}}) {
    const fs::path out = dir / ("out" + std::to_string(blocks));
    const CliRun r = cli("unroll " + seq.string() + " --out " + out.string() + " --times 0.5 --quiet",
                      "ulimit -f " + std::to_string(blocks) + "; ");
    EXPECT_EQ(r.rc, 74) << r.out;
    EXPECT_TRUE(has(r, (out / file).string())) << r.out;
    EXPECT_TRUE(has(r, "File too large")) << r.out;
    EXPECT_FALSE(has(r, "wrote")) << r.out;
    EXPECT_FALSE(fs::exists(out)) << "a failed run left " << out;
    EXPECT_FALSE(fs::exists(dir / (".out" + std::to_string(blocks) + ".partial")));
  }
  fs::remove_all(dir);
}

// Found: kill -9 into an old output left the old summary.json beside a mix of old and new frames;
// into a fresh folder, a 44-byte gs_video.mp4 under its final name.
TEST(Cli, KilledRunLeavesNothingThatClaimsSuccess) {
  const fs::path dir = temp_dir("kill");
  const fs::path seq = make_sequence(dir), out = dir / "out", staging = dir / ".out.partial";
  ASSERT_EQ(cli("unroll " + seq.string() + " --out " + out.string() + " --times 0.5 --quiet").rc, 0);
  const std::string old_summary = slurp(out / "summary.json");
  const auto old_frames = files_in(out / "frames");
  ASSERT_EQ(old_frames.size(), 3u);

  for (const bool fresh : {false, true}) {
    const fs::path target = fresh ? dir / "fresh" : out, stage = fresh ? dir / ".fresh.partial" : staging;
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::execl(VKUNROLL_CLI_PATH, VKUNROLL_CLI_PATH, "unroll", seq.c_str(), "--out", target.c_str(), "--times", "0:1:300",
              "--overwrite", "--quiet", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    // Kill it once it has staged a few frames (600 to go: it is far from done).
    const vkunroll::Stopwatch waiting;
    while (files_in(stage / "frames").size() < 3 && waiting.seconds() < 120)
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    ::kill(pid, SIGKILL);
    int st = 0;
    ::waitpid(pid, &st, 0);
    ASSERT_TRUE(WIFSIGNALED(st)) << "the run finished before it was killed";
    if (fresh) {
      EXPECT_FALSE(fs::exists(target)) << "a killed run left its final-named folder";
    } else {
      EXPECT_EQ(slurp(out / "summary.json"), old_summary);  // the old output, whole and unmixed
      EXPECT_EQ(files_in(out / "frames"), old_frames);
    }
    EXPECT_FALSE(fs::exists(stage / "summary.json"));
  }
  fs::remove_all(dir);
}

// Found: a re-run with other --times left the old frames in frames/. An existing output is refused
// without --overwrite, and replaced whole with it.
TEST(Cli, RerunReplacesTheOutputWholeOnlyWithOverwrite) {
  const fs::path dir = temp_dir("rerun");
  const fs::path seq = make_sequence(dir), out = dir / "out";
  const std::string base = "unroll " + seq.string() + " --out " + out.string() + " --quiet --no-video";
  ASSERT_EQ(cli(base + " --times 0.25,0.75").rc, 0);
  EXPECT_EQ(files_in(out / "frames").size(), 6u);
  CliRun r = cli(base + " --times 0.5");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(has(r, "--overwrite")) << r.out;
  EXPECT_EQ(files_in(out / "frames").size(), 6u);  // untouched
  r = cli(base + " --times 0.5 --overwrite");
  ASSERT_EQ(r.rc, 0) << r.out;
  const auto frames = files_in(out / "frames");
  EXPECT_EQ(frames.size(), 3u);
  const auto summary = read_json(out / "summary.json");
  EXPECT_EQ(summary["targets"], 3);
  for (const auto& rec : summary["gs_frames"]) EXPECT_TRUE(fs::exists(out / rec["file"].get<std::string>())) << rec;
  // A folder that is not a vkunroll output is never replaced.
  fs::create_directories(dir / "mine");
  std::ofstream(dir / "mine" / "thesis.tex") << "x";
  r = cli("unroll " + seq.string() + " --out " + (dir / "mine").string() + " --overwrite --quiet");
  EXPECT_EQ(r.rc, 2) << r.out;
  EXPECT_TRUE(fs::exists(dir / "mine" / "thesis.tex"));
  fs::remove_all(dir);
}

// --resume keeps the GS frames already written and valid, and redoes a damaged one.
TEST(Cli, ResumeReusesValidFramesAndRedoesDamagedOnes) {
  const fs::path dir = temp_dir("resume");
  const fs::path seq = make_sequence(dir), out = dir / "out";
  const std::string base = "unroll " + seq.string() + " --out " + out.string() + " --times 0.25,0.75 --quiet --contrast 0.25";
  ASSERT_EQ(cli(base).rc, 0);
  const auto first = read_json(out / "summary.json");
  const std::string damaged = first["gs_frames"][1]["file"];
  std::ofstream(out / damaged, std::ios::app) << "garbage";
  const CliRun r = cli(base + " --resume");
  ASSERT_EQ(r.rc, 0) << r.out;
  const auto again = read_json(out / "summary.json");
  EXPECT_EQ(again["resume"]["reused"], 5) << again["resume"];
  EXPECT_EQ(again["resume"]["computed"], 1) << again["resume"];
  EXPECT_EQ(slurp(out / damaged).find("garbage"), std::string::npos);
  // Another option that changes pixels: nothing is reused.
  ASSERT_EQ(cli("unroll " + seq.string() + " --out " + out.string() + " --times 0.25,0.75 --quiet --contrast 0.3 --resume").rc, 0);
  EXPECT_EQ(read_json(out / "summary.json")["resume"]["reused"], 0);
  fs::remove_all(dir);
}

// Found: an empty event file gave exit 0 and the RS input back with nothing said.
TEST(Cli, EmptyEventFileWarnsOnStderrAndInSummary) {
  const fs::path dir = temp_dir("noev");
  const fs::path seq = make_sequence(dir), out = dir / "out";
  std::ofstream(dir / "empty.txt").close();
  const CliRun r = cli("unroll " + seq.string() + " --out " + out.string() + " --events " + (dir / "empty.txt").string() +
                    " --contrast 0.2 --quiet");
  ASSERT_EQ(r.rc, 0) << r.out;
  EXPECT_TRUE(has(r, "warning: no events")) << r.out;
  const auto s = read_json(out / "summary.json");
  ASSERT_FALSE(s["warnings"].empty());
  EXPECT_NE(s["warnings"].dump().find("no events"), std::string::npos) << s["warnings"];
  EXPECT_NE(s["warnings"].dump().find("empty (0 bytes)"), std::string::npos) << s["warnings"];
  EXPECT_EQ(s["events"]["in_frame_windows"], 0);
  EXPECT_EQ(s["events"]["file_totals"]["empty_files"], 1);
  fs::remove_all(dir);
}

// Found: a sequence whose meta.json was deleted silently switched to the Gev-RS layout.
TEST(Cli, MissingMetaJsonIsSaid) {
  const fs::path dir = temp_dir("nometa");
  // With events.h5 beside rs/ and gs/, the folder also looks like Gev-RS (200 us rows, 3200 us exposure).
  const fs::path seq = dir / "seq", out = dir / "out";
  ASSERT_EQ(cli("simulate --out " + seq.string() + " --preset clean --size 64x48 --frames 3 --events-format h5 --quiet").rc, 0);
  fs::remove(seq / "meta.json");
  const CliRun r = cli("unroll " + seq.string() + " --out " + out.string() + " --quiet");
  if (r.rc == 0) {  // read with another layout's timing: said on stderr and in summary.json
    EXPECT_TRUE(has(r, "no meta.json")) << r.out;
    const auto s = read_json(out / "summary.json");
    EXPECT_NE(s["warnings"].dump().find("no meta.json"), std::string::npos) << s["warnings"];
  } else {  // or refused as bad or missing input, naming the file
    EXPECT_TRUE(r.rc == 65 || r.rc == 66) << r.out;
    EXPECT_TRUE(has(r, "meta.json")) << r.out;
  }
  fs::remove_all(dir);
}

// Found: --on-bad drop never said how many events it dropped.
TEST(Cli, OnBadDropCountsTheDroppedEvents) {
  const fs::path dir = temp_dir("drop");
  const fs::path seq = make_sequence(dir), out = dir / "out", ev = dir / "bad.txt";
  // Two records outside the 64x48 sensor, inside frame 0's window only (frame 1 starts at 60000 us).
  std::ofstream(ev) << "# t x y p\n12000 3 4 1\n12001 64 4 0\n12002 5 48 1\n13000 5 5 0\n";
  const std::string base = "unroll " + seq.string() + " --out " + out.string() + " --events " + ev.string() +
                           " --contrast 0.2 --times 0.5 --quiet";
  CliRun r = cli(base);
  EXPECT_EQ(r.rc, 65) << r.out;  // bad input data, naming the file
  EXPECT_TRUE(has(r, ev.string())) << r.out;
  r = cli(base + " --on-bad drop");
  ASSERT_EQ(r.rc, 0) << r.out;
  EXPECT_TRUE(has(r, "2 of 4 event record(s) broke a rule and were dropped")) << r.out;
  const auto s = read_json(out / "summary.json");
  EXPECT_EQ(s["events"]["file_totals"]["dropped"], 2) << s["events"];
  EXPECT_NE(s["warnings"].dump().find("were dropped"), std::string::npos) << s["warnings"];
  fs::remove_all(dir);
}

// Found: vague messages. Each names the option, file or variable, with the right exit code, and
// the prefix is said once.
TEST(Cli, MessagesNameTheOptionAndExitCodesFollowSysexits) {
  const fs::path dir = temp_dir("msg");
  const fs::path seq = make_sequence(dir), out = dir / "out";
  const std::string u = "unroll " + seq.string() + " --out " + out.string() + " --quiet";
  struct Case {
    std::string args, env, needle;
    int rc;
  };
  const std::vector<Case> cases = {
      {u + " --model " + dir.string(), "", "is a folder", 65},
      {u + " --contrast inf", "", "--contrast: 'inf' is not a finite number", 2},
      {u + " --t0s-us 9223372036854775000,9223372036854775100,9223372036854775200", "", "--t0s-us", 2},
      {u + " --t0s-us 110000,60000,17700", "", "--t0s-us: value 2 (60000 us) is not after value 1", 2},
      {u, "VKUNROLL_DEVICE=nosuch ", "VKUNROLL_DEVICE 'nosuch'", 69},
      {u + " --device uuid:ffff", "", "--device 'uuid:ffff': no device has that UUID", 69},
      {"unroll --out " + out.string(), "", "SEQUENCE is required", 2},
      {"simulate --out " + (dir / "s").string() + " --size 0x48", "", "--size '0x48'", 2},
      {"unroll " + (dir / "nothere").string() + " --out " + out.string(), "", "nothere", 66},
      {"frobnicate", "", "unknown command 'frobnicate'", 2},
      {u + " --frames 99", "", "--frames: " + seq.string() + ": frame 99 does not exist", 2},
      // Numbers a sensor cannot have and empty values (issue 28): refused, naming the option.
      {u + " --gamma 1e300", "", "--gamma 1", 2},
      {u + " --gamma 1e300", "", "expected a decode gamma in [0.1, 10]", 2},
      {u + " --contrast 1e9", "", "expected a log-intensity threshold in (0, 5]", 2},
      {u + " --line-delay-us 1e12", "", "--line-delay-us 1000000000000: expected 0 to 1e6 us", 2},
      {u + " --frames \"\"", "", "--frames: empty value", 2},
  };
  for (const auto& c : cases) {
    const CliRun r = cli(c.args, c.env);
    EXPECT_EQ(r.rc, c.rc) << c.args << "\n" << r.out;
    EXPECT_TRUE(has(r, c.needle)) << c.args << "\n" << r.out;
    EXPECT_FALSE(has(r, "error: vkunroll")) << "prefix repeated: " << r.out;
    EXPECT_FALSE(has(r, "bad_alloc")) << r.out;
    EXPECT_FALSE(fs::exists(out));
  }
  fs::remove_all(dir);
}

// The help is generated from the declarations: shared timing names, device options everywhere.
TEST(Cli, HelpListsTheSharedOptionGroups) {
  for (const std::string cmd : {"unroll", "voxelize"}) {
    const CliRun r = cli(cmd + " --help");
    EXPECT_EQ(r.rc, 0) << r.out;
    for (const char* opt : {"--line-delay-us", "--exposure-us", "--t0s-us", "--gev-half-row", "--on-bad", "--device", "--threads"})
      EXPECT_TRUE(has(r, opt)) << cmd << " --help lacks " << opt;
  }
  EXPECT_TRUE(has(cli("demo --help"), "--device"));
  const CliRun r = cli("--help");
  EXPECT_TRUE(has(r, "Exit codes")) << r.out;
}

// summary.json carries where the result came from; metrics.csv times are full-precision decimals.
TEST(Cli, SummaryCarriesProvenanceAndMetricsKeepUnixMicroseconds) {
  const fs::path dir = temp_dir("prov");
  const fs::path seq = make_sequence(dir), out = dir / "out";
  const CliRun devs = cli("devices --json");
  ASSERT_EQ(devs.rc, 0) << devs.out;
  const auto list = nlohmann::json::parse(devs.out.substr(devs.out.find('{')));
  const std::string uuid = list["devices"][0]["uuid"];
  const CliRun r = cli("unroll " + seq.string() + " --out " + out.string() + " --quiet --no-video --contrast 0.2 --device uuid:" +
                    uuid + " --t0s-us 1700000000010000,1700000000060000,1700000000110000 --times 0.5 --threads 1 --frame-format npy");
  ASSERT_EQ(r.rc, 0) << r.out;
  const auto s = read_json(out / "summary.json");
  const auto& p = s["provenance"];
  EXPECT_EQ(p["device"]["uuid"], uuid);
  EXPECT_FALSE(p["git_revision"].get<std::string>().empty());
  EXPECT_FALSE(p["device"]["driver_version"].get<std::string>().empty());
  EXPECT_EQ(p["precision"], "fp32");
  EXPECT_EQ(p["command_line"][1], "unroll");
  EXPECT_EQ(p["threads"]["lavapipe_workers"], 1) << p["threads"];  // --threads bounds lavapipe's workers
  EXPECT_EQ(p["threads"]["opencv"], 1) << p["threads"];
  // --frame-format npy: float32 [H, W, 3] NumPy arrays.
  const std::string npy = slurp(out / s["gs_frames"][0]["file"].get<std::string>());
  EXPECT_EQ(npy.substr(0, 6), "\x93NUMPY");
  EXPECT_NE(npy.find("'descr': '<f4'"), std::string::npos);
  EXPECT_NE(npy.find("'shape': (48, 64, 3)"), std::string::npos);
  const std::string csv = slurp(out / "metrics.csv");
  EXPECT_EQ(csv.find("e+"), std::string::npos) << csv;
  EXPECT_NE(csv.find("\n0,1700000000013850,0.5,"), std::string::npos) << csv;  // t* of frame 0, to the us
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 4) << csv;       // a row per GS frame without ground truth
  fs::remove_all(dir);
}

// A second run into an output another run is writing is refused as temporary (exit 75: retry).
TEST(Cli, ConcurrentRunIntoTheSameOutputIsBusy) {
  const fs::path dir = temp_dir("busy");
  const fs::path seq = make_sequence(dir), out = dir / "out", stage = dir / ".out.partial";
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::execl(VKUNROLL_CLI_PATH, VKUNROLL_CLI_PATH, "unroll", seq.c_str(), "--out", out.c_str(), "--times", "0:1:300", "--quiet",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const vkunroll::Stopwatch waiting;
  while (files_in(stage / "frames").empty() && waiting.seconds() < 120)
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  const CliRun r = cli("unroll " + seq.string() + " --out " + out.string() + " --overwrite --quiet");
  ::kill(pid, SIGKILL);
  int st = 0;
  ::waitpid(pid, &st, 0);
  EXPECT_EQ(r.rc, 75) << r.out;
  EXPECT_TRUE(has(r, "another vkunroll run is writing this output")) << r.out;
  fs::remove_all(dir);
}

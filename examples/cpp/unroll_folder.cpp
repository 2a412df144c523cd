// Unrolls a recording folder (the generic layout, docs/usage.md) with the default model through the
// library's UnrollJob, the job behind `vkunroll unroll`, and prints each GS frame it gets.
//   unroll_folder SEQUENCE_FOLDER [TIMES]     TIMES as --times: "0.5" (default), "0:1:5", "gt"
#include <cstdio>
#include <vkunroll/base/error.hpp>
#include <vkunroll/host/events/sequence.hpp>
#include <vkunroll/host/unroll/default_model.hpp>
#include <vkunroll/host/unroll/metrics.hpp>
#include <vkunroll/host/unroll/unroll_job.hpp>

// A sink receives every GS frame (BGR float32); the CLI's writes files, this one prints.
struct PrintingSink : vkunroll::ResultSink {
  int count = 0;
  void add(const vkunroll::GsResult& r) override {
    ++count;
    std::printf("frame %d t=%.1f us: %dx%d GS image", r.frame, r.target->t_us.to_double(), r.image.cols, r.image.rows);
    if (!r.ground_truth.empty()) std::printf(", PSNR %.2f dB against the ground truth", vkunroll::psnr(r.image, r.ground_truth));
    std::printf("\n");
  }
};

int main(int argc, char** argv) {
  if (argc < 2 || argc > 3) {
    std::fprintf(stderr, "usage: %s SEQUENCE_FOLDER [TIMES]\n", argv[0]);
    return 64;
  }
  try {
    vkunroll::UnrollOptions options;
    options.sequence = argv[1];
    options.times = vkunroll::parse_target_times(argc > 2 ? argv[2] : "0.5");
    const vkunroll::ModelChoice model = vkunroll::choose_model(options.mode, "");  // the default model
    options.session.model_path = model.path;
    const vkunroll::Sequence seq = vkunroll::load_sequence(options.sequence);
    vkunroll::UnrollSession session(options.session);
    vkunroll::SequenceFrameSource source(seq);
    vkunroll::UnrollJob job(options, session, source);  // plans: errors name the option
    PrintingSink sink;
    job.run(sink);
    std::printf("%d GS frames, model %s (%s)\n", sink.count, model.path.c_str(), model.source.c_str());
  } catch (const vkunroll::Error& e) {
    std::fprintf(stderr, "unroll_folder: %s\n", e.what());
    return 1;
  }
}

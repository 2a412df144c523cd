// UnrollSession: everything one unroll job holds, built once from typed options — the device
// context, the backend (Vulkan or CPU, behind one interface), the model, the event-tensor builder
// and the physics unroller — and the per-frame work: RS frame(s) + events -> GS images.
//
// Per frame the data stays on the device: one upload of the RS image and of the frame's events,
// event tensors built into device buffers the network reads in place, tiles cut and stitched on the
// device, the GS images downloaded once. A group of targets (physics, S, M) is one submission.
//
//   UnrollSession session({.backend = BackendKind::vulkan, .model_path = "m.safetensors"});
//   auto images = session.unroll(frame_input, {{t_us, FrameTarget::Method::s}});
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "vkunroll/base/events.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/trace.hpp"

namespace vkunroll {

class Backend;
class EventTensorBuilder;
class Model;

struct FrameTarget {
  enum class Method { s, m, physics };
  Rational t_us;
  Method method = Method::s;
};

const char* frame_method_name(FrameTarget::Method m);  // "s", "m", "physics"
FrameTarget::Method parse_frame_method(const std::string& s, const std::string& what);

// One RS frame's inputs.
struct FrameInput {
  cv::Mat rs1;          // BGR float32 in [0, 1], the sensor's size
  cv::Mat rs2;          // the next frame (needed by M targets)
  RowTiming timing1, timing2;
  // The events of every target's window: [min(t*, first row start), max(t* + exposure, last row end)].
  const EventStream* events = nullptr;
};

// The host stages a GS frame's time is split into (summary.json's ms_per_gs_frame keys): the job's
// (setup, read, contrast_estimate, write) and the session's (upload ... download), and the device
// waits and driver shader builds inside them, counted once.
enum class Stage { setup, read, contrast_estimate, upload, event_tensors, physics, model, download, write, wait, pipeline_builds };
const char* stage_name(Stage s);  // "setup", "read", ...

// What the session did, summed over its frames.
struct SessionStats {
  size_t runs_s = 0, runs_m = 0, runs_physics = 0;
  size_t frames_unrolled = 0;  // unroll() calls
  size_t image_uploads = 0;    // RS images uploaded: one per frame, two with M targets, whatever the targets
  size_t physics_on_cpu = 0;  // physics targets with a pixel beyond the GPU kernel's event limit
  // Targets whose full-frame event tensors exceed one storage-buffer binding: memory forced the host
  // path (tensors built, downloaded, and cut into tiles on the host).
  size_t host_path_targets = 0;
  int64_t tiles = 0, tiles_run = 0;
  int64_t tile_used = 0;        // tile interior of the last model run (0: untiled)
  int64_t tiles_per_target = 0;
  double work_pixels = 0;       // sum over targets of the tiled run's work ratio
  std::vector<double> target_active_fraction;
  // Host milliseconds per stage, device waits excluded: "upload" (planes, staging copies),
  // "event_tensors" (planning, recording), "physics" (gathering, recording), "model" (tiling plan,
  // recording the network), "download" (planes to images); "wait", the time blocked on the
  // device (submitting, the fence, reading back); "pipeline_builds" (the driver compiling shaders,
  // the first frames). They add up to the session's wall time.
  std::map<Stage, double> ms;
};

class UnrollSession {
 public:
  explicit UnrollSession(const SessionOptions& options);
  ~UnrollSession();
  UnrollSession(const UnrollSession&) = delete;
  UnrollSession& operator=(const UnrollSession&) = delete;

  bool has_model() const { return model_ != nullptr; }
  const Weights& weights() const;  // throws Error without a model
  const ModelConfig& model_config() const { return weights().config; }
  BackendKind backend_kind() const { return options_.backend; }
  Backend& backend() { return *backend_; }
  const Backend& backend() const { return *backend_; }
  const Context* context() const { return ctx_.get(); }  // null on the CPU backend
  // GPU ms per op (kernel) summed over the session's dispatches: SessionOptions::profile_ops on
  // the Vulkan backend, else null.
  const Profiler* profiler() const { return profiler_.get(); }
  // The timeline of host stages and GPU dispatches: SessionOptions::trace on the Vulkan backend, else null.
  const Trace* trace() const { return trace_.get(); }
  // Host <-> device traffic and submissions since the session started (zeros on the CPU backend).
  DeviceTraffic traffic() const;
  // The most bytes one tensor may hold: the device's binding limit, or the tiling's lower one.
  // Event tensors beyond it take the host path (SessionStats::host_path_targets).
  uint64_t binding_limit() const;
  // Submissions the backend made because released buffers held too much memory.
  uint64_t memory_forced_submits() const;
  uint64_t peak_device_bytes() const;
  // The conv algorithm choice (Vulkan): what was asked, the table's file (empty: none), entries
  // used by recorded convs, shapes timed in this session. The table is saved when the session ends.
  nlohmann::json conv_choice_report() const;
  // Writes the table's new timings to its file now (the destructor does it too); warnings on stderr.
  void save_conv_choices();

  // The model's input channel order (default: the weights' metadata), tiling, physics parameters.
  void set_model_rgb(bool rgb) { rgb_ = rgb; }
  bool model_rgb() const { return rgb_; }
  void set_tiling(const TileOptions& t) { tiling_ = t; }
  // Physics parameters: of --mode physics targets, and of the physics-informed variant's input
  // (whose gamma is the model's encoding; unroll converts the frames to it).
  void set_physics(const PhysicsUnrollParams& p) { physics_ = p; }
  // The variant's event gate radius as the weights' metadata gave it (-1: no gate, or no model), and
  // the one the model runs with: set_gate_radius rebuilds the model when it changes (before a run).
  int metadata_gate_radius() const { return metadata_gate_radius_; }
  void set_gate_radius(int r);

  // The GS images (BGR float32 in [0, 1], the sensor's size) of `targets`, in their order.
  std::vector<cv::Mat> unroll(const FrameInput& in, const std::vector<FrameTarget>& targets);
  const SessionStats& stats() const { return stats_; }

 private:
  // A frame's RS image(s) as planes in the device's channel order (the model's; BGR without a
  // model), converted once and uploaded once for every target group of the frame.
  struct FramePlanes {
    std::vector<float> rs1, rs2;  // host planes [3, H, W]; rs2 empty without M targets
    Buffer rs1_buf, rs2_buf;  // rs2_buf empty without M targets
    bool rgb = false;
  };
  FramePlanes upload_frame(const FrameInput& in, bool with_next);
  // Times one host stage into stats_.ms (less the device waits inside it) and tags the ops it
  // records with the stage; next() ends it and starts another.
  class StageClock {
   public:
    StageClock(UnrollSession& s, Stage stage);
    ~StageClock() { stop(); }
    void next(Stage stage);
    void stop();

   private:
    UnrollSession& s_;
    std::optional<Stage> stage_;
    Clock::time_point t0_;
    DeviceTraffic before_;
  };
  void run_physics(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                   const std::vector<size_t>& which, std::vector<cv::Mat>& results);
  void run_model(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                 const std::vector<size_t>& which, bool m, std::vector<cv::Mat>& results);
  void run_model_on_host(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                         const std::vector<size_t>& which, bool m, std::vector<cv::Mat>& results);
  void add_tile_stats(const TileStats& run, size_t targets, int H, int W);
  // The physics-informed variant's input: [B, 3, H, W] physics estimates of the batch's (frame,
  // target) pairs, computed on the device from the uploaded frames (model order).
  Buffer physics_input(const FrameInput& in, const FramePlanes& fp, const std::vector<EventTensorPair>& pairs);
  // One physics estimate of the frame `rs` (its host planes `rs_planes`) with `lists`: recorded on
  // the device into `out` when every pixel's events fit the kernel (PhysicsUnroll::fits); else the
  // CPU reference's planes, returned (counted in stats_.physics_on_cpu) and `out` left as it is.
  std::optional<std::vector<float>> physics_estimate(const BufferSlice& rs, const std::vector<float>& rs_planes,
                                                     const PixelEventLists& lists, const BufferSlice& out);

  SessionOptions options_;
  std::unique_ptr<Trace> trace_;  // SessionOptions::trace (before the context that points to it)
  std::unique_ptr<Context> ctx_;
  std::unique_ptr<Profiler> profiler_;  // SessionOptions::profile_ops (declared before the backend that records into it)
  std::string conv_choice_path_;  // the table's file (empty: none)
  std::string conv_committed_table_, conv_committed_how_;  // a committed table merged in (empty: none)
  std::unique_ptr<Backend> backend_;
  std::unique_ptr<Weights> weights_;
  std::unique_ptr<Model> model_;
  int metadata_gate_radius_ = -1;
  std::unique_ptr<EventTensorBuilder> host_builder_;  // the host path's event tensors (Vulkan)
  bool rgb_ = true;
  TileOptions tiling_;
  PhysicsUnrollParams physics_;
  SessionStats stats_;
};

}  // namespace vkunroll

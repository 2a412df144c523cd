#include "vkunroll/host/unroll/session.hpp"

#include <algorithm>
#include <iterator>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/make_backend.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/unroll/backend_options.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/image_planes.hpp"
#include "vkunroll/kernels/event_tensor.hpp"

namespace vkunroll {

namespace {

// One group's network run: M ends in "out", S in "fused" (the only output the session reads).
RunOptions group_run_options(bool m) {
  RunOptions ro;
  ro.mode = m ? Mode::m : Mode::s;
  ro.outputs = {m ? ModelOutput::out : ModelOutput::fused};
  return ro;
}

}  // namespace

const char* stage_name(Stage s) {
  static const char* const names[] = {"setup", "read",     "contrast_estimate", "upload", "event_tensors",  // in Stage's order
                                      "physics", "model", "download", "write", "wait", "pipeline_builds"};
  static_assert(std::size(names) == static_cast<size_t>(Stage::pipeline_builds) + 1);
  const auto i = static_cast<size_t>(s);
  return i < std::size(names) ? names[i] : "?";
}

UnrollSession::StageClock::StageClock(UnrollSession& s, Stage stage) : s_(s) { next(stage); }

void UnrollSession::StageClock::next(Stage stage) {
  stop();
  stage_ = stage;
  t0_ = Clock::now();
  before_ = s_.traffic();
  s_.backend_->set_stage(stage_name(stage));
}

// The stage's host time is its wall time less the device waits and the pipeline builds inside
// it, which count once, as "wait" and "pipeline_builds".
void UnrollSession::StageClock::stop() {
  if (!stage_) return;
  const DeviceTraffic now = s_.traffic();
  const double wait = now.wait_ms - before_.wait_ms, builds = now.pipeline_build_ms - before_.pipeline_build_ms;
  s_.stats_.ms[*stage_] += std::max(0.0, ms_since(t0_) - wait - builds);
  s_.stats_.ms[Stage::wait] += wait;
  s_.stats_.ms[Stage::pipeline_builds] += builds;
  if (s_.trace_) s_.trace_->host_span("host stages", stage_name(*stage_), t0_, Clock::now());
  stage_.reset();
}

const char* frame_method_name(FrameTarget::Method m) {
  switch (m) {
    case FrameTarget::Method::s: return "s";
    case FrameTarget::Method::m: return "m";
    case FrameTarget::Method::physics: return "physics";
  }
  return "?";
}

FrameTarget::Method parse_frame_method(const std::string& s, const std::string& what) {
  if (s == "s") return FrameTarget::Method::s;
  if (s == "m") return FrameTarget::Method::m;
  if (s == "physics") return FrameTarget::Method::physics;
  throw UsageError(what + " '" + s + "': expected s, m or physics");
}

UnrollSession::UnrollSession(const SessionOptions& o) : options_(o) {
  check_session_options_apply(o);
  if (!o.model_path.empty()) {
    weights_ = std::make_unique<Weights>(load_weights(o.model_path));
    rgb_ = weights_->config.channel_order != "bgr";
    if (weights_->config.physics_input) metadata_gate_radius_ = weights_->config.physics_gate;
  }
  if (o.backend == BackendKind::vulkan && o.profile_ops) profiler_ = std::make_unique<Profiler>();
  OpenedBackend opened = make_backend({.kind = o.backend,
                                       .precision = o.precision,
                                       .device = o.device,
                                       .announce = o.announce,
                                       .cpu_threads = o.cpu_threads,
                                       .conv_choice = o.conv_choice,
                                       .committed_conv_tables = conv_table_dirs(),
                                       .profiler = profiler_.get()});
  ctx_ = std::move(opened.context);
  backend_ = std::move(opened.backend);
  conv_choice_path_ = opened.conv_table.path;
  conv_committed_table_ = opened.conv_table.committed;
  conv_committed_how_ = opened.conv_table.committed_how;
  if (ctx_) {
    ctx_->set_timestamps(o.profile_ops || o.trace);  // the device's timestamps cost time: only when asked for
    if (o.trace) {
      trace_ = std::make_unique<Trace>();
      ctx_->set_trace(trace_.get());
    }
  }
  if (weights_) model_ = std::make_unique<Model>(*backend_, *weights_);
}

void UnrollSession::set_gate_radius(int r) {
  if (!weights_ || r == weights_->config.physics_gate) return;
  if (metadata_gate_radius_ < 0 || r < 0) throw UsageError("unroll session: this model has no event gate to set");
  weights_->config.physics_gate = r;
  model_ = std::make_unique<Model>(*backend_, *weights_);
}

UnrollSession::~UnrollSession() {
  try {
    save_conv_choices();
  } catch (...) {
  }
}

void UnrollSession::save_conv_choices() {
  const ConvChoiceTable* table = backend_->conv_table();
  if (!table || !table->changed() || conv_choice_path_.empty() || !ctx_) return;
  try {
    table->save(conv_choice_path_, conv_choice_header(*ctx_), conv_device_identity(*ctx_));
  } catch (const std::exception& e) {
    log_warning(std::string("vkunroll: warning: the measured conv algorithms were not saved: ") + e.what());
  }
}

nlohmann::json UnrollSession::conv_choice_report() const {
  if (options_.backend != BackendKind::vulkan) return nullptr;
  const ConvChoiceTable* table = backend_->conv_table();
  return {{"choice", conv_choice_name(options_.conv_choice)},
          {"table", conv_choice_path_},
          {"committed_table", conv_committed_table_},
          {"committed_table_match", conv_committed_how_},
          {"table_entries", table ? table->entries().size() : 0},
          {"convs_from_table", backend_->convs_from_table()},
          {"shapes_timed", backend_->convs_timed()},
          {"calls_by_algorithm", backend_->conv_calls_by_algorithm()}};
}

const Weights& UnrollSession::weights() const {
  if (!weights_) throw UsageError("unroll session: no model was given (physics only)");
  return *weights_;
}

DeviceTraffic UnrollSession::traffic() const { return ctx_ ? ctx_->traffic() : DeviceTraffic{}; }

uint64_t UnrollSession::binding_limit() const {
  const uint64_t device = backend_->max_buffer_bytes();
  return tiling_.max_buffer_bytes ? std::min(tiling_.max_buffer_bytes, device) : device;
}

uint64_t UnrollSession::memory_forced_submits() const { return backend_->pool_flushes(); }

uint64_t UnrollSession::peak_device_bytes() const {
  const uint64_t allocated = ctx_ ? ctx_->allocator().stats().peak_used_bytes : 0;
  return std::max(allocated, backend_->device_peak_bytes());
}

UnrollSession::FramePlanes UnrollSession::upload_frame(const FrameInput& in, bool with_next) {
  StageClock clock(*this, Stage::upload);
  FramePlanes fp;
  fp.rgb = model_ ? rgb_ : false;  // physics is per channel: any order serves it
  const int H = in.rs1.rows, W = in.rs1.cols;
  fp.rs1 = image_planes(in.rs1, fp.rgb);
  fp.rs1_buf = backend_->alloc({1, 3, H, W}, "rs1");
  backend_->upload(fp.rs1_buf.whole(), fp.rs1);
  stats_.image_uploads++;
  if (with_next) {
    fp.rs2 = image_planes(in.rs2, fp.rgb);
    fp.rs2_buf = backend_->alloc({1, 3, H, W}, "rs2");
    backend_->upload(fp.rs2_buf.whole(), fp.rs2);
    stats_.image_uploads++;
  }
  return fp;
}

void UnrollSession::add_tile_stats(const TileStats& run, size_t targets, int H, int W) {
  stats_.tiles += run.tiles;
  stats_.tiles_run += run.tiles_run;
  stats_.work_pixels += run.work_ratio * double(targets);
  stats_.tile_used = run.plan.tile_h == H && run.plan.tile_w == W ? 0 : std::max(run.plan.tile_h, run.plan.tile_w);
  stats_.tiles_per_target = static_cast<int64_t>(run.plan.tiles.size());
  for (double a : run.target_active_fraction) stats_.target_active_fraction.push_back(a);
}

std::vector<cv::Mat> UnrollSession::unroll(const FrameInput& in, const std::vector<FrameTarget>& targets) {
  if (!in.events) throw UsageError("unroll session: the frame's events are missing");
  if (in.rs1.type() != CV_32FC3 || in.rs1.cols != in.events->width || in.rs1.rows != in.events->height)
    throw DataError("unroll session: the RS frame must be a float BGR image of the event sensor's size (" +
                std::to_string(in.events->width) + "x" + std::to_string(in.events->height) + ")");
  std::vector<size_t> groups[3];  // s, m, physics
  for (size_t j = 0; j < targets.size(); ++j) groups[static_cast<int>(targets[j].method)].push_back(j);
  if ((!groups[0].empty() || !groups[1].empty()) && !model_)
    throw UsageError("unroll session: SelfUnroll-S/-M targets need a model (" + opt("model") + " FILE.safetensors)");
  if (!groups[1].empty() && (in.rs2.empty() || in.rs2.size() != in.rs1.size()))
    throw UsageError("unroll session: SelfUnroll-M targets need the next RS frame");
  std::vector<cv::Mat> results(targets.size());
  stats_.frames_unrolled++;
  if (targets.empty()) return results;
  const FramePlanes fp = upload_frame(in, !groups[1].empty());  // its buffers go with it, also on an error
  if (!groups[2].empty()) run_physics(in, fp, targets, groups[2], results);
  if (!groups[0].empty()) run_model(in, fp, targets, groups[0], false, results);
  if (!groups[1].empty()) run_model(in, fp, targets, groups[1], true, results);
  return results;
}

void UnrollSession::run_physics(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                                const std::vector<size_t>& which, std::vector<cv::Mat>& results) {
  Backend& b = *backend_;
  const int H = in.rs1.rows, W = in.rs1.cols;
  StageClock clock(*this, Stage::physics);
  const std::vector<float>& rs = fp.rs1;
  const auto starts = in.timing1.start_times_us(), ends = in.timing1.end_times_us();
  std::vector<std::pair<size_t, Buffer>> on_device;  // (target, output buffer)
  for (size_t j : which) {
    const PixelEventLists lists = gather_pixel_events(*in.events, targets[j].t_us.to_double(), starts, ends, 0, 0, W, H);
    check_physics_image(rs, 3, lists);
    Buffer out = b.alloc({1, 3, H, W}, "physics");
    if (const auto on_cpu = physics_estimate(fp.rs1_buf.whole(), rs, lists, out.whole())) {
      results[j] = planes_image(on_cpu->data(), H, W, fp.rgb);
      continue;
    }
    on_device.emplace_back(j, std::move(out));
  }
  clock.next(Stage::download);
  std::vector<std::vector<float>> planes(on_device.size(), std::vector<float>(size_t(3) * H * W));
  for (size_t q = 0; q < on_device.size(); ++q) b.download(on_device[q].second.whole(), planes[q]);
  b.flush();
  for (size_t q = 0; q < on_device.size(); ++q) {
    results[on_device[q].first] = planes_image(planes[q].data(), H, W, fp.rgb);
    on_device[q].second.reset();
  }
  clock.stop();
  stats_.runs_physics += which.size();
}

Buffer UnrollSession::physics_input(const FrameInput& in, const FramePlanes& fp, const std::vector<EventTensorPair>& pairs) {
  Backend& b = *backend_;
  const int H = in.rs1.rows, W = in.rs1.cols;
  const int64_t B = static_cast<int64_t>(pairs.size());
  Buffer phys = b.alloc({B, 3, H, W}, "phys");
  for (int64_t i = 0; i < B; ++i) {
    const bool second = fp.rs2_buf.id() >= 0 && i % 2 == 1;  // M: items 2k + 1 are the next frame
    const RowTiming& t = second ? in.timing2 : in.timing1;
    const PixelEventLists lists = gather_pixel_events(*in.events, pairs[size_t(i)].target_us.to_double(), t.start_times_us(),
                                                      t.end_times_us(), 0, 0, W, H);
    const BufferSlice dst = phys.items(i, 1);  // into the batch, in place
    if (const auto on_cpu = physics_estimate((second ? fp.rs2_buf : fp.rs1_buf).whole(), second ? fp.rs2 : fp.rs1, lists, dst))
      b.upload(dst, *on_cpu);
  }
  return phys;
}

std::optional<std::vector<float>> UnrollSession::physics_estimate(const BufferSlice& rs, const std::vector<float>& rs_planes,
                                                                  const PixelEventLists& lists, const BufferSlice& out) {
  if (PhysicsUnroll::fits(lists)) {
    backend_->physics_unroll(rs, lists, physics_, out);
    return std::nullopt;
  }
  stats_.physics_on_cpu++;  // a pixel beyond the GPU kernel's loop limit: the CPU reference has none
  return physics_unroll_ref(rs_planes, 3, lists, physics_);
}

void UnrollSession::run_model(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                              const std::vector<size_t>& which, bool m, std::vector<cv::Mat>& results) {
  Backend& b = *backend_;
  const int H = in.rs1.rows, W = in.rs1.cols;
  const int64_t per = m ? 2 : 1;
  // The event tensors of a build ([3B, 2N, H, W]) live in one binding: as many targets per build as fit.
  const uint64_t per_target = uint64_t(3 * per) * 2 * model_->config().N * H * W * 4;
  const size_t fit = static_cast<size_t>(binding_limit() / per_target);
  if (fit == 0) return run_model_on_host(in, fp, targets, which, m, results);
  if (which.size() > fit) {
    for (size_t i = 0; i < which.size(); i += fit)
      run_model(in, fp, targets, std::vector<size_t>(which.begin() + i, which.begin() + std::min(which.size(), i + fit)), m, results);
    return;
  }
  const int64_t B = static_cast<int64_t>(which.size()) * per;
  StageClock clock(*this, Stage::model);
  // The RS frame(s), uploaded once per frame, repeated on the device for every target of the batch.
  int rs = fp.rs1_buf.id();
  Buffer rs_batch;
  if (B > 1) {
    rs_batch = b.alloc({B, 3, H, W}, "rs batch");
    rs = rs_batch.id();
    for (int64_t i = 0; i < B; ++i) b.copy(((m && i % 2) ? fp.rs2_buf : fp.rs1_buf).whole(), rs_batch.items(i, 1));
  }
  std::vector<EventTensorPair> pairs;
  for (size_t j : which) {
    pairs.push_back({in.timing1, targets[j].t_us, std::nullopt});
    if (m) pairs.push_back({in.timing2, targets[j].t_us, std::nullopt});
  }
  EventTensorSpec spec;
  spec.bins = model_->config().N;
  clock.next(Stage::event_tensors);
  const Buffer ev = b.event_tensors(*in.events, pairs, spec);
  ModelBuffers inputs{{rs, 0, B, 0, 3}, ev.items(0, B), ev.items(B, B), ev.items(2 * B, B)};
  Buffer phys;
  if (model_->config().physics_input) {
    clock.next(Stage::physics);
    phys = physics_input(in, fp, pairs);
    inputs.phys = phys.whole();
    clock.next(Stage::event_tensors);
  }
  ActivityTables activity;
  if (tiling_.sparse != SparsePolicy::off) activity = activity_tables(selected_event_counts(*in.events, pairs, spec), H, W);
  clock.next(Stage::model);
  const RunOptions ro = group_run_options(m);
  const ModelOutput wanted = ro.outputs[0];
  const TiledBuffers run = run_tiled_on_backend(*model_, inputs, ro, tiling_, &activity);
  clock.next(Stage::download);
  std::vector<float> planes(static_cast<size_t>(which.size()) * 3 * H * W);
  b.download(run.outputs.at(wanted).whole(), planes);
  b.flush();
  for (size_t q = 0; q < which.size(); ++q)
    results[which[q]] = planes_image(planes.data() + q * 3 * H * W, H, W, rgb_);
  clock.stop();
  add_tile_stats(run, which.size(), H, W);
  (m ? stats_.runs_m : stats_.runs_s) += which.size();
}

void UnrollSession::run_model_on_host(const FrameInput& in, const FramePlanes& fp, const std::vector<FrameTarget>& targets,
                                      const std::vector<size_t>& which, bool m, std::vector<cv::Mat>& results) {
  const int H = in.rs1.rows, W = in.rs1.cols;
  const int64_t per = m ? 2 : 1;
  EventTensorSpec spec;
  spec.bins = model_->config().N;
  const std::vector<float>& p1 = fp.rs1;
  const std::vector<float>& p2 = fp.rs2;
  for (size_t j : which) {  // one target at a time: the host copies of its tensors are large already
    StageClock clock(*this, Stage::event_tensors);
    std::vector<EventTensorPair> pairs{{in.timing1, targets[j].t_us, std::nullopt}};
    if (m) pairs.push_back({in.timing2, targets[j].t_us, std::nullopt});
    if (ctx_ && !host_builder_) host_builder_ = std::make_unique<EventTensorBuilder>(*ctx_);
    EventTensors et = host_builder_ ? host_builder_->build(*in.events, pairs, spec) : build_event_tensors_ref(*in.events, pairs, spec);
    const Shape es{per, 2 * spec.bins, H, W};
    ModelInputs mi;
    mi.rs = HostTensor(Shape{per, 3, H, W});
    std::copy(p1.begin(), p1.end(), mi.rs.data.begin());
    if (m) std::copy(p2.begin(), p2.end(), mi.rs.data.begin() + p1.size());
    mi.ev1 = HostTensor(es, std::move(et.ev1));
    mi.ev2 = HostTensor(es, std::move(et.ev2));
    mi.ev3 = HostTensor(es, std::move(et.ev3));
    if (model_->config().physics_input) {
      mi.phys = HostTensor(Shape{per, 3, H, W});
      for (int64_t i = 0; i < per; ++i) {
        const RowTiming& t = i ? in.timing2 : in.timing1;
        const PixelEventLists lists = gather_pixel_events(*in.events, targets[j].t_us.to_double(), t.start_times_us(),
                                                          t.end_times_us(), 0, 0, W, H);
        const std::vector<float> gs = physics_unroll_ref(i ? p2 : p1, 3, lists, physics_);
        std::copy(gs.begin(), gs.end(), mi.phys.data.begin() + i * 3 * H * W);
      }
    }
    clock.next(Stage::model);
    const RunOptions ro = group_run_options(m);
    const ModelOutput wanted = ro.outputs[0];
    const TiledResult run = run_tiled(*model_, mi, ro, tiling_);
    clock.stop();
    results[j] = planes_image(run.outputs.at(wanted).data.data(), H, W, rgb_);
    add_tile_stats(run, 1, H, W);
    stats_.host_path_targets++;
  }
  (m ? stats_.runs_m : stats_.runs_s) += which.size();
}

}  // namespace vkunroll

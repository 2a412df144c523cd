// vkunroll bag-sequence: a generic sequence folder from a ROS bag alone (frames from an image topic,
// events read from the bag in place, row timing from the options); see docs/rosbags.md.
#include <iostream>
#include <memory>

#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/events/rosbag_sequence.hpp"
#include "vkunroll/host/unroll/output_folder.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll::cli {

namespace {

struct BagSequenceArgs {
  std::string bag, out, frames_topic, events_topic, line_delay, exposure, readout = "top-down", t0_offset = "0";
  uint64_t max_frames = 0;
  bool overwrite = false;
};

Rational exact_option(const std::string& text, const std::string& name) {
  try {
    return Rational::parse(text, name);
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
}

int run_bag_sequence(const BagSequenceArgs& a) {
  check_output_folder(a.out, "OUT");
  check_output_apart(a.out, "bag_sequence_out", {{"BAG", a.bag}});
  BagSequenceOptions o;
  o.frames_topic = a.frames_topic;
  o.events_topic = a.events_topic;
  o.line_delay_us = exact_option(a.line_delay, "--line-delay-us");
  o.exposure_us = exact_option(a.exposure, "--exposure-us");
  o.t0_offset_us = exact_option(a.t0_offset, "--t0-offset-us");
  // The rules (and texts) of unroll's timing overrides; a bag's camera also needs a line delay > 0.
  SequenceOptions timing;
  timing.line_delay_us = o.line_delay_us;
  timing.exposure_us = o.exposure_us;
  timing.t0s_us = std::vector<Rational>{o.t0_offset_us};
  try {
    validate_sequence_options(timing);
  } catch (const OptionError& e) {
    if (e.field() == "t0s_us") throw UsageError("--t0-offset-us " + a.t0_offset + ": not a time vkunroll can hold");
    throw;
  }
  if (!(Rational(0) < o.line_delay_us))
    throw UsageError("--line-delay-us " + a.line_delay + ": expected > 0 us (a bag does not hold the row timing)");
  o.readout = parse_readout(a.readout);
  o.max_frames = a.max_frames;
  BagSequenceReport r;
  try {
    // The output rule of every writer: staged, checked by the loader's schema, then committed.
    OutputFolder folder(a.out, a.overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse, output_path("bag-sequence.out"));
    r = write_bag_sequence(a.bag, folder.staging().string(), o);
    check_written_sequence(folder.staging().string(), a.out);
    folder.commit();
  } catch (const Error& e) {  // a topic the bag lacks is the option's fault: name it
    const std::string m = e.text();
    for (const auto& [option, topic] : {std::pair<std::string, std::string>{"--frames-topic", a.frames_topic}, {"--events-topic", a.events_topic}})
      if (!topic.empty() && m.find("has no topic '" + topic + "'") != std::string::npos) throw UsageError(option + ": " + m);
    throw;
  }
  std::cout << "sequence     " << a.out << "\n"
            << "frames       " << r.frames << " from " << r.frames_topic << " (" << r.encoding << ", " << r.width << "x"
            << r.height << ")\n"
            << "events       " << r.events_topic << " (read from the bag in place)\n";
  if (!r.camera_info_topic.empty())
    std::cout << "camera info  " << r.camera_info_topic << " (recorded in meta.json's source.camera_info; not used to unroll)\n";
  for (const auto& n : r.notes) std::cout << "note         " << n << "\n";
  return 0;
}

}  // namespace

Command add_bag_sequence(CLI::App& parent) {
  auto a = std::make_shared<BagSequenceArgs>();
  CLI::App* c = parent.add_subcommand("bag-sequence", "a sequence folder from a ROS bag: RS frames of an image topic + its events");
  c->description(
      "Writes OUT/rs/NNNNNN.png from a sensor_msgs/Image topic and OUT/meta.json (the generic layout) whose\n"
      "events are the bag itself; each frame's t0 is its header stamp (+ --t0-offset-us). A bag holds no\n"
      "row timing: give --line-delay-us and --exposure-us. Then: vkunroll unroll OUT [--events-topic T].");
  c->add_option("BAG", a->bag, "the ROS 1 bag")->required();
  add_output_option(c, "bag-sequence.out", a->out)->required();
  c->add_option("--frames-topic", a->frames_topic, "the sensor_msgs/Image topic (default: the bag's only one)")->check(non_empty())->type_name("TOPIC");
  c->add_option("--events-topic", a->events_topic, "the event topic (default: the bag's only one)")->check(non_empty())->type_name("TOPIC");
  c->add_option("--line-delay-us", a->line_delay, "row-to-row start delay of the RS camera (exact: '73000/259')")
      ->required()->type_name("US");
  c->add_option("--exposure-us", a->exposure, "row exposure")->required()->type_name("US");
  c->add_option("--readout", a->readout, "top-down | bottom-up")
      ->check(CLI::IsMember({"top-down", "bottom-up"}))->capture_default_str()->type_name("DIR");
  c->add_option("--t0-offset-us", a->t0_offset, "added to each header stamp to give the first row's exposure start")
      ->capture_default_str()->type_name("US");
  c->add_option("--max-frames", a->max_frames, "write at most N frames (0: all)")->type_name("N");
  c->add_flag("--overwrite", a->overwrite, "replace an existing OUT (only a folder vkunroll wrote: its manifest lists everything)");
  return {c, [a] { return run_bag_sequence(*a); }};
}

}  // namespace vkunroll::cli

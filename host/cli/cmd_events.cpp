#include <cstdio>
#include <filesystem>
#include <iostream>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/events/event_formats.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll::cli {

namespace {

struct EventsArgs {
  std::string file, format, on_bad = "error", window, columns = "txyp", time_unit, array_time_unit, events_topic;
  std::optional<int> width, height;
  bool json = false;
};

int64_t parse_time(const std::string& s, const std::string& whole) {
  try {
    size_t used = 0;
    const long long v = std::stoll(s, &used);
    if (used != s.size()) throw std::invalid_argument(s);
    return v;
  } catch (const std::exception&) {
    throw UsageError("--window-us expects A:B in integer microseconds (either side may be empty), got '" + whole + "'");
  }
}

EventReadOptions to_options(const EventsArgs& a) {
  EventReadOptions o;
  o.format = a.format;
  o.on_bad = a.on_bad == "drop" ? BadEventPolicy::drop : a.on_bad == "sort" ? BadEventPolicy::sort : BadEventPolicy::error;
  if (!a.window.empty()) {
    const auto colon = a.window.find(':');
    if (colon == std::string::npos) throw UsageError("--window-us expects A:B (microseconds), got '" + a.window + "'");
    const std::string lo = a.window.substr(0, colon), hi = a.window.substr(colon + 1);
    if (!lo.empty()) o.t_begin_us = parse_time(lo, a.window);
    if (!hi.empty()) o.t_end_us = parse_time(hi, a.window);
    if (o.t_begin_us && o.t_end_us && *o.t_end_us < *o.t_begin_us)
      throw UsageError("--window-us " + a.window + ": the window ends before it begins");
  }
  if (a.width.has_value() != a.height.has_value())
    throw UsageError(std::string(a.width ? "--width" : "--height") + " given without " + (a.width ? "--height" : "--width") +
                     ": the sensor size needs both");
  o.width = a.width.value_or(0);
  o.height = a.height.value_or(0);
  if (const std::string problem = text_columns_problem(a.columns); !problem.empty())
    throw UsageError("--columns '" + a.columns.substr(0, 64) + (a.columns.size() > 64 ? "...'" : "'") + " " + problem);
  o.text_columns = a.columns;
  o.text_time_unit = a.time_unit;
  o.array_time_unit = a.array_time_unit;
  o.events_topic = a.events_topic;
  return o;
}

// One line a format, from the table: "  evt3        a Prophesee EVT 3.0 recording (.raw)".
std::string format_list() {
  std::string out;
  for (const EventFormat& f : event_formats()) {
    std::string names = std::string(f.name) + (f.alias.empty() ? "" : "/" + std::string(f.alias)), exts;
    for (std::string_view e : f.extensions)
      if (!e.empty()) exts += (exts.empty() ? "" : " ") + std::string(e);
    out += "\n  " + names + std::string(names.size() < 10 ? 10 - names.size() : 1, ' ') + std::string(f.what) + " (" + exts + ")";
  }
  return out;
}

int run_events(const EventsArgs& a) {
  std::error_code ec;
  if (!std::filesystem::exists(a.file, ec)) throw InputMissingError(a.file + ": no such event file");
  if (std::filesystem::is_directory(a.file, ec)) throw DataError(a.file + ": is a folder, expected an event file");
  const EventReadOptions o = to_options(a);
  uint64_t n = 0, pos = 0;
  int64_t t_first = 0, t_last = 0;
  int64_t t_min = std::numeric_limits<int64_t>::max(), t_max = std::numeric_limits<int64_t>::min();
  EventReadReport report;
  const Stopwatch scanning;
  scan_events(a.file, o,
              [&](const EventStream& c) {
                if (n == 0 && !c.empty()) t_first = c.t.front();
                for (size_t i = 0; i < c.size(); ++i) {
                  pos += c.p[i] > 0;
                  t_min = std::min(t_min, c.t[i]);
                  t_max = std::max(t_max, c.t[i]);
                }
                if (!c.empty()) t_last = c.t.back();
                n += c.size();
              },
              &report);
  const double secs = scanning.seconds();
  const double span = n ? double(t_max - t_min) : 0.0;
  if (a.json) {
    nlohmann::json j = {{"file", a.file}, {"format", report.format}, {"events", n},
                        {"sensor", report.width == 0 ? nlohmann::json(nullptr)  // no events, no size given: unknown
                                             : nlohmann::json{{"width", report.width}, {"height", report.height}, {"inferred", report.size_inferred}}},
                        {"records", report.records}, {"outside_window", report.outside_window},
                        {"dropped", {{"total", report.dropped()}, {"out_of_sensor", report.dropped_out_of_sensor},
                                     {"time_order", report.dropped_time_order}, {"nan_time", report.dropped_nan},
                                     {"bad_polarity", report.dropped_bad_polarity}, {"unknown_word", report.dropped_unknown_word}}},
                        {"sorted", report.sorted}, {"ignored", report.ignored}, {"notes", report.notes}, {"read_s", secs}};
    if (n) {
      j["t_first_us"] = t_first, j["t_last_us"] = t_last, j["t_min_us"] = t_min, j["t_max_us"] = t_max;
      j["span_s"] = span * 1e-6;
      j["rate_mev_s"] = span > 0 ? nlohmann::json(double(n) / span) : nlohmann::json();
      j["polarity"] = {{"on", pos}, {"off", n - pos}};
    }
    std::cout << j.dump(2) << "\n";
    return 0;
  }
  std::printf("file        %s\n", a.file.c_str());
  std::printf("format      %s\n", report.format.c_str());
  std::printf("events      %llu\n", static_cast<unsigned long long>(n));
  if (report.width == 0) std::printf("sensor      unknown (no events to infer it from; pass --width and --height)\n");
  else std::printf("sensor      %dx%d%s\n", report.width, report.height, report.size_inferred ? " (inferred from max x, y)" : "");
  if (n > 0) {
    std::printf("time        %lld .. %lld us (span %.6f s)\n", static_cast<long long>(t_first),
                static_cast<long long>(t_last), span * 1e-6);
    if (span > 0) std::printf("rate        %.3f Mev/s\n", double(n) / span);
    else std::printf("rate        n/a (zero time span)\n");
    std::printf("polarity    %llu on (+1), %llu off (-1), %.2f%% on\n", static_cast<unsigned long long>(pos),
                static_cast<unsigned long long>(n - pos), 100.0 * double(pos) / double(n));
  }
  std::printf("records     %llu read, %llu outside the window\n", static_cast<unsigned long long>(report.records),
              static_cast<unsigned long long>(report.outside_window));
  std::printf("dropped     %llu (out of sensor %llu, time order %llu, NaN time %llu, bad polarity %llu, unknown word %llu)\n",
              static_cast<unsigned long long>(report.dropped()),
              static_cast<unsigned long long>(report.dropped_out_of_sensor),
              static_cast<unsigned long long>(report.dropped_time_order),
              static_cast<unsigned long long>(report.dropped_nan),
              static_cast<unsigned long long>(report.dropped_bad_polarity),
              static_cast<unsigned long long>(report.dropped_unknown_word));
  if (report.sorted) std::printf("sorted      yes (out-of-order records were sorted by t)\n");
  for (const auto& [k, v] : report.ignored)
    std::printf("ignored     %llu %s\n", static_cast<unsigned long long>(v), k.c_str());
  for (const auto& note : report.notes) std::printf("note        %s\n", note.c_str());
  std::printf("read speed  %.2f Mev/s (%.3f s)\n", secs > 0 ? double(report.records) / secs * 1e-6 : 0.0, secs);
  return 0;
}

}  // namespace

Command add_events(CLI::App& parent) {
  auto a = std::make_shared<EventsArgs>();
  CLI::App* c = parent.add_subcommand("events", "read an event file: count, time span, rate, sensor size, polarity, drops");
  c->description(
      "Reads an event file in bounded memory and prints the event count, time span, rate, sensor size, polarity\n"
      "balance, read speed, and what was dropped or ignored. Formats (--format; detected from the file's signature,\n"
      "then its extension):" + format_list());
  c->add_option("FILE", a->file, "the event file")->required();
  std::vector<std::string> names;
  for (const EventFormat& f : event_formats()) names.emplace_back(f.name);
  c->add_option("--format", a->format, event_format_names() + " (default: detect)")
      ->check(CLI::IsMember(names))
      ->type_name("F");
  c->add_option("--on-bad", a->on_bad,
                "error: stop at the first bad record | drop: drop and count bad records | sort: keep out-of-order "
                "records and sort by t")
      ->check(CLI::IsMember({"error", "drop", "sort"}))->capture_default_str()->type_name("P");
  c->add_option("--window-us", a->window, "read only A <= t < B (microseconds; 'A:' or ':B' for open ends)")->type_name("A:B");
  c->add_option("--width", a->width, "sensor width when the file lacks it (or to override it; with --height)")
      ->check(int_range(1, 32767))->type_name("W");
  c->add_option("--height", a->height, "sensor height (with --width)")->check(int_range(1, 32767))->type_name("H");
  c->add_option("--columns", a->columns, "text column order ('_' skips a column; text and CSV files only)")->capture_default_str()->type_name("ORDER");
  c->add_option("--time-unit", a->time_unit, "unit of text times: s, ms, us, ns (default: auto, see docs/events.md)")
      ->check(CLI::IsMember({"s", "ms", "us", "ns"}))->type_name("U");
  c->add_option("--array-time-unit", a->array_time_unit, "unit of float time arrays in npy/npz/h5 (default us)")
      ->check(CLI::IsMember({"s", "ms", "us", "ns"}))->type_name("U");
  c->add_option("--events-topic", a->events_topic,
                "ROS bags: the event topic to read (default: the bag's only topic of an event type)")
      ->type_name("TOPIC");
  c->add_flag("--json", a->json, "print the report as JSON");
  return {c, [a] { return run_events(*a); }};
}

}  // namespace vkunroll::cli

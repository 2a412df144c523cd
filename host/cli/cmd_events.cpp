#include <chrono>
#include <cstdio>
#include <iostream>
#include <limits>

#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll::cli {

namespace {

BadEventPolicy parse_policy(const std::string& s) {
  if (s == "error") return BadEventPolicy::error;
  if (s == "drop") return BadEventPolicy::drop;
  if (s == "sort") return BadEventPolicy::sort;
  throw Error("vkunroll events: --on-bad expects error, drop or sort, got '" + s + "'");
}

int64_t parse_time(const std::string& s, const std::string& whole) {
  try {
    size_t used = 0;
    const long long v = std::stoll(s, &used);
    if (used != s.size()) throw std::invalid_argument(s);
    return v;
  } catch (const std::exception&) {
    throw Error("vkunroll events: --window-us expects A:B in integer microseconds (either side may be empty), got '" +
                whole + "'");
  }
}

}  // namespace

int cmd_events(const Argv& argv) {
  Args args("events", argv, {"format", "on-bad", "window-us", "width", "height", "columns", "time-unit", "array-time-unit"});
  if (args.help() || args.positionals().size() != 1) {
    std::cout << "usage: vkunroll events FILE [--format F] [--on-bad error|drop|sort] [--window-us A:B]\n"
                 "                        [--width W --height H] [--columns txyp] [--time-unit s|ms|us|ns]\n"
                 "                        [--array-time-unit s|ms|us|ns]\n\n"
                 "Reads an event file (txt/csv, h5, npy, npz, Prophesee evt2/evt3 .raw and .dat, AEDAT 4) in\n"
                 "bounded memory and prints the event count, time span, rate, sensor size, polarity balance,\n"
                 "read speed, and what was dropped or ignored.\n"
                 "  --format      txt, h5, npy, npz, evt2, evt3, dat, aedat4 (default: detect)\n"
                 "  --on-bad      error (default): stop at the first bad record; drop: drop and count bad\n"
                 "                records; sort: keep out-of-order records and sort by t\n"
                 "  --window-us   A:B reads only A <= t < B (microseconds; 'A:' or ':B' for open ends)\n"
                 "  --width/--height  sensor size when the file lacks it (or to override it)\n"
                 "  --columns     text column order (default txyp; '_' skips a column)\n"
                 "  --time-unit   unit of text times (default: auto, see docs/events.md)\n"
                 "  --array-time-unit  unit of float time arrays in npy/npz/h5 (default us)\n";
    return args.help() ? 0 : 2;
  }
  const std::string path = args.positionals()[0];
  EventReadOptions o;
  o.format = args.get_or("format", "");
  o.on_bad = parse_policy(args.get_or("on-bad", "error"));
  if (auto w = args.get("window-us")) {
    const auto colon = w->find(':');
    if (colon == std::string::npos)
      throw Error("vkunroll events: --window-us expects A:B (microseconds), got '" + *w + "'");
    const std::string a = w->substr(0, colon), b = w->substr(colon + 1);
    if (!a.empty()) o.t_begin_us = parse_time(a, *w);
    if (!b.empty()) o.t_end_us = parse_time(b, *w);
  }
  o.width = int(args.integer("width", 0));
  o.height = int(args.integer("height", 0));
  if ((o.width > 0) != (o.height > 0)) throw Error("vkunroll events: give both --width and --height");
  o.text_columns = args.get_or("columns", "txyp");
  o.text_time_unit = args.get_or("time-unit", "");
  o.array_time_unit = args.get_or("array-time-unit", "");

  uint64_t n = 0, pos = 0;
  int64_t t_first = 0, t_last = 0;
  int64_t t_min = std::numeric_limits<int64_t>::max(), t_max = std::numeric_limits<int64_t>::min();
  EventReadReport report;
  const auto start = std::chrono::steady_clock::now();
  scan_events(path, o,
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
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("file        %s\n", path.c_str());
  std::printf("format      %s\n", report.format.c_str());
  std::printf("events      %llu\n", static_cast<unsigned long long>(n));
  std::printf("sensor      %dx%d%s\n", report.width, report.height, report.size_inferred ? " (inferred from max x, y)" : "");
  if (n > 0) {
    const double span = double(t_max - t_min);
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

}  // namespace vkunroll::cli

// Event files (read_events / write_events) and RowTiming.
#include "common.hpp"
#include "output_rule.hpp"
#include "vkunroll/host/events/event_formats.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/event_writer.hpp"

namespace vkunroll::python {

using namespace pybind11::literals;

BadEventPolicy parse_on_bad(const std::string& s) {
  if (s == "error") return BadEventPolicy::error;
  if (s == "drop") return BadEventPolicy::drop;
  if (s == "sort") return BadEventPolicy::sort;
  throw UsageError("on_bad '" + s + "': expected error, drop or sort");
}

py::dict report_dict(const EventReadReport& r) {
  py::dict d;
  d["format"] = r.format;
  d["path"] = r.path;
  d["records"] = r.records;
  d["kept"] = r.kept;
  d["outside_window"] = r.outside_window;
  add_drop_counts(d, r);
  d["sorted"] = r.sorted;
  d["empty_file"] = r.empty_file;
  d["size_inferred"] = r.size_inferred;
  d["stopped_early"] = r.stopped_early;
  d["width"] = r.width;
  d["height"] = r.height;
  d["time_unit"] = r.time_unit;
  d["ignored"] = r.ignored;
  d["notes"] = r.notes;
  d["summary"] = r.summary();
  return d;
}

static EventReadOptions read_options(const py::object& t_begin, const py::object& t_end, const std::string& format,
                              const std::string& on_bad, int width, int height, const std::string& columns,
                              const std::string& time_unit, const std::string& array_time_unit) {
  EventReadOptions o;
  if (!t_begin.is_none()) o.t_begin_us = t_begin.cast<int64_t>();
  if (!t_end.is_none()) o.t_end_us = t_end.cast<int64_t>();
  o.format = format;
  o.on_bad = parse_on_bad(on_bad);
  o.width = width;
  o.height = height;
  if (!columns.empty()) {
    if (const std::string problem = text_columns_problem(columns); !problem.empty())
      throw UsageError("columns '" + columns.substr(0, 64) + (columns.size() > 64 ? "...'" : "'") + " " + problem);
    o.text_columns = columns;
  }
  o.text_time_unit = time_unit;
  o.array_time_unit = array_time_unit;
  return o;
}

namespace {

// RowTiming as a value: ==, repr and pickling (its times as exact rational strings).
void add_value_protocols(py::class_<RowTiming>& cls) {
  cls.def(
          "__eq__",
          [](const RowTiming& a, const RowTiming& b) {
            return a.rows == b.rows && a.t0 == b.t0 && a.line_delay == b.line_delay && a.exposure == b.exposure &&
                   a.readout == b.readout;
          },
          py::is_operator())
      .def("__repr__",
           [](const RowTiming& t) {
             return "RowTiming(height=" + std::to_string(t.rows) + ", t0_us=" + t.t0.str() + ", line_delay_us=" +
                    t.line_delay.str() + ", exposure_us=" + t.exposure.str() + ", readout='" + readout_name(t.readout) + "')";
           })
      .def(py::pickle(
          [](const RowTiming& t) {
            return py::make_tuple(t.rows, t.t0.str(), t.line_delay.str(), t.exposure.str(), std::string(readout_name(t.readout)));
          },
          [](const py::tuple& s) {
            RowTiming t;
            t.rows = s[0].cast<int>();
            t.t0 = Rational::parse(s[1].cast<std::string>());
            t.line_delay = Rational::parse(s[2].cast<std::string>());
            t.exposure = Rational::parse(s[3].cast<std::string>());
            t.readout = parse_readout(s[4].cast<std::string>());
            return t;
          }));
}

// RowTiming as a Python class: exact times in, fractions.Fraction out.
void bind_row_timing(py::module_& m) {
  py::class_<RowTiming> cls(m, "RowTiming", R"doc(
Rolling-shutter timing of one frame, in exact rational microseconds.

RowTiming(height, t0_us, line_delay_us, exposure_us, readout="top-down")

Row y is read as the r-th row, r = y (top-down) or height-1-y (bottom-up); it is exposed over
[t0 + r * line_delay, t0 + r * line_delay + exposure]. Times may be ints, floats (taken as the
simplest fraction that rounds to them: 0.1 -> 1/10), strings ("73000/259", "2.5e3") or
fractions.Fraction; they come back as fractions.Fraction, so nothing is rounded on the way.
)doc");
  cls.def(py::init([](const py::object& height, const py::object& t0, const py::object& delay, const py::object& exposure,
                       const py::object& readout) {
             // Types and ranges by the API's one rule (vkunroll/_args.py), naming the keyword.
             const py::module_ args = py::module_::import("vkunroll._args");
             const int rows = args.attr("integer")("RowTiming", "height", height, 1, 65536).cast<int>();
             args.attr("exact_time")("RowTiming", "t0_us", t0);
             args.attr("exact_time")("RowTiming", "line_delay_us", delay, "nonnegative"_a = true);
             args.attr("exact_time")("RowTiming", "exposure_us", exposure, "positive"_a = true);
             const std::string order = args.attr("choice")("RowTiming", "readout", readout,
                                                           py::make_tuple("top-down", "bottom-up")).cast<std::string>();
             return guarded({}, [&] {
               RowTiming t;
               t.rows = rows;
               t.t0 = to_rational(t0, "t0_us");
               t.line_delay = to_rational(delay, "line_delay_us");
               t.exposure = to_rational(exposure, "exposure_us");
               t.readout = parse_readout(order);
               t.validate("RowTiming");
               return t;
             });
           }),
           py::arg("height"), py::arg("t0_us"), py::arg("line_delay_us"), py::arg("exposure_us"),
           py::arg("readout") = "top-down")
      .def_property_readonly("height", [](const RowTiming& t) { return t.rows; }, "Sensor rows H.")
      .def_property_readonly("t0_us", [](const RowTiming& t) { return to_fraction(t.t0); },
                             "Exposure start of the first row read out (Fraction, us).")
      .def_property_readonly("line_delay_us", [](const RowTiming& t) { return to_fraction(t.line_delay); },
                             "Start of read-out row r+1 minus start of row r (Fraction, us).")
      .def_property_readonly("exposure_us", [](const RowTiming& t) { return to_fraction(t.exposure); },
                             "Exposure of one row (Fraction, us).")
      .def_property_readonly("readout", [](const RowTiming& t) { return std::string(readout_name(t.readout)); },
                             "'top-down' or 'bottom-up'.")
      .def_property_readonly("first_start_us", [](const RowTiming& t) { return to_fraction(t.first_start()); },
                             "Exposure start of the first row read out (Fraction, us).")
      .def_property_readonly("last_end_us", [](const RowTiming& t) { return to_fraction(t.last_end()); },
                             "Exposure end of the last row read out (Fraction, us).")
      .def(
          "start_us",
          [](const RowTiming& t, const py::object& y) {
            const int row = py::module_::import("vkunroll._args").attr("integer")("RowTiming.start_us", "y", y, 0, t.rows - 1).cast<int>();
            return guarded({}, [&] { return to_fraction(t.start(row)); });
          },
          py::arg("y"), "Exposure start of sensor row y (Fraction, us).")
      .def(
          "end_us",
          [](const RowTiming& t, const py::object& y) {
            const int row = py::module_::import("vkunroll._args").attr("integer")("RowTiming.end_us", "y", y, 0, t.rows - 1).cast<int>();
            return guarded({}, [&] { return to_fraction(t.end(row)); });
          },
          py::arg("y"), "Exposure end of sensor row y (Fraction, us).")
      .def(
          "start_times_us",
          [](const RowTiming& t) {
            auto v = t.start_times_us();
            const auto n = static_cast<py::ssize_t>(v.size());
            return to_numpy(std::move(v), {n});
          },
          "Exposure start of every sensor row, float64 us (what the physics unroller reads).")
      .def(
          "end_times_us",
          [](const RowTiming& t) {
            auto v = t.end_times_us();
            const auto n = static_cast<py::ssize_t>(v.size());
            return to_numpy(std::move(v), {n});
          },
          "Exposure end of every sensor row, float64 us.")
      .def(
          "target_time",
          [](const RowTiming& t, const py::object& tau) {
            const py::module_ args = py::module_::import("vkunroll._args");
            args.attr("exact_time")("RowTiming.target_time", "tau", tau, "what"_a = "a normalized instant tau (0 = the first "
                                    "row's exposure start, 1 = the last row's exposure end; not microseconds)",
                                    "limit"_a = 1000000, "within"_a = "+-1e6 frame spans");
            return guarded({}, [&] { return to_fraction(t.target_time(to_rational(tau, "tau"))); });
          },
          py::arg("tau"),
          "t* = t0 + tau * (last_end - t0) (Fraction, us): tau 0 is the first row's exposure start, 1 the last row's "
          "exposure end; outside [0, 1] lies between frames.")
      .def(
          "tau_of",
          [](const RowTiming& t, const py::object& t_us) {
            py::module_::import("vkunroll._args").attr("exact_time")("RowTiming.tau_of", "t_us", t_us);
            return guarded({}, [&] { return to_fraction(t.tau_of(to_rational(t_us, "t_us"))); });
          },
          py::arg("t_us"), "The normalized instant of t_us (the inverse of target_time), a Fraction.");
  add_value_protocols(cls);
}

}  // namespace

void bind_events(py::module_& m) {
  m.def(
      "_read_events",
      [](const std::string& path, const py::object& t_begin, const py::object& t_end, const std::string& format,
         const std::string& on_bad, int width, int height, const std::string& columns, const std::string& time_unit,
         const std::string& array_time_unit, const std::string& topic) {
        EventReadOptions o = guarded({{path}}, [&] {
          return read_options(t_begin, t_end, format, on_bad, width, height, columns, time_unit, array_time_unit);
        });
        o.events_topic = topic;
        EventReadReport report;
        EventStream ev = without_gil({{path}}, [&] { return read_events(path, o, &report); });
        report.path = path;
        return py::make_tuple(from_event_stream(std::move(ev)), report_dict(report));
      },
      py::arg("path"), py::arg("t_begin"), py::arg("t_end"), py::arg("format"), py::arg("on_bad"), py::arg("width"),
      py::arg("height"), py::arg("columns"), py::arg("time_unit"), py::arg("array_time_unit"), py::arg("topic") = "");

  // The library's one grammar for exact times (Rational::parse), for vkunroll/_args.py.
  m.def("_parse_time", [](const std::string& text, const std::string& what) {
    return guarded({}, [&] { return to_fraction(Rational::parse(text, what)); });
  });

  // The format table (event_formats.hpp), for vkunroll.EVENT_FORMATS and the argument checks.
  m.def("_event_formats", [] {
    py::list rows;
    for (const EventFormat& f : event_formats()) {
      py::list exts;
      for (std::string_view e : f.extensions)
        if (!e.empty()) exts.append(std::string(e));
      py::dict row;
      row["name"] = std::string(f.name), row["alias"] = std::string(f.alias), row["what"] = std::string(f.what);
      row["extensions"] = py::tuple(exts), row["signature"] = std::string(f.signature), row["streamed"] = f.streamed;
      row["reader"] = std::string(f.reader), row["writable"] = f.write != nullptr, row["fuzzer"] = std::string(f.fuzzer);
      rows.append(row);
    }
    return rows;
  });

  m.def("_detect_event_format", [](const std::string& path) {
    return guarded({{path}}, [&] { return detect_event_format(path); });
  });

  m.def(
      "_write_events",
      [](const std::string& path, const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, int width,
         int height, const std::string& format, bool overwrite) {
        EventStream ev = guarded({}, [&] { return to_event_stream(t, x, y, p, width, height); });
        without_gil({}, [&] {
          const EventFormat* f = find_event_format(format);
          if (!f || !f->write)
            throw OptionError("format", format, "one of " + event_format_names(", ", true));
          write_output_file("write_events.path", path, overwrite, [&](const std::string& tmp) { f->write(tmp, ev); });
        });
      },
      py::arg("path"), py::arg("t"), py::arg("x"), py::arg("y"), py::arg("p"), py::arg("width"), py::arg("height"),
      py::arg("format"), py::arg("overwrite"));

  bind_row_timing(m);
}

}  // namespace vkunroll::python

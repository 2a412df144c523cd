// Sequences: load any supported layout, read frames and events by window, write the generic layout.
#include "common.hpp"
#include "output_rule.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/events/sequence_writer.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll::python {

namespace {

// SequenceOptions from Sequence.open's keyword arguments (None: the layout's own value).
SequenceOptions sequence_options(const py::dict& kw) {
  SequenceOptions o;
  auto has = [&](const char* k) { return kw.contains(k) && !kw[k].is_none(); };
  if (has("layout")) o.layout = parse_sequence_layout(kw["layout"].cast<std::string>());
  if (has("line_delay_us")) o.line_delay_us = to_rational(kw["line_delay_us"], "line_delay_us");
  if (has("exposure_us")) o.exposure_us = to_rational(kw["exposure_us"], "exposure_us");
  if (has("readout")) o.readout = parse_readout(kw["readout"].cast<std::string>());
  if (has("t0s_us")) o.t0s_us = to_rationals(kw["t0s_us"].cast<py::sequence>(), "t0s_us");
  if (has("frame_period_us")) o.frame_period_us = to_rational(kw["frame_period_us"], "frame_period_us");
  if (has("gev_half_row")) o.gev_half_row = kw["gev_half_row"].cast<bool>();
  if (has("fastec_frame_step_gs")) o.fastec_frame_step_gs = kw["fastec_frame_step_gs"].cast<int>();
  if (has("events_file")) o.events_file = kw["events_file"].cast<std::string>();
  if (has("events_topic")) o.events.events_topic = kw["events_topic"].cast<std::string>();
  if (has("on_bad")) o.events.on_bad = parse_on_bad(kw["on_bad"].cast<std::string>());
  if (has("check_frame_sizes")) o.check_frame_sizes = kw["check_frame_sizes"].cast<bool>();
  for (auto item : kw) {
    const std::string k = py::str(item.first);
    static const char* known[] = {"layout", "line_delay_us", "exposure_us", "readout", "t0s_us", "frame_period_us",
                                  "gev_half_row", "fastec_frame_step_gs", "events_file", "events_topic", "on_bad",
                                  "check_frame_sizes"};
    if (std::none_of(std::begin(known), std::end(known), [&](const char* n) { return k == n; }))
      throw UsageError("Sequence.open: unknown option '" + k + "'");
  }
  return o;
}

// An image array (H x W or H x W x C, uint8 or uint16) -> SequenceImage.
SequenceImage sequence_image(const py::array& a, const std::string& what) {
  SequenceImage im;
  if (a.ndim() != 2 && a.ndim() != 3) throw UsageError(what + ": expected an H x W or H x W x 3 image");
  im.height = static_cast<int>(a.shape(0));
  im.width = static_cast<int>(a.shape(1));
  im.channels = a.ndim() == 3 ? static_cast<int>(a.shape(2)) : 1;
  const size_t n = static_cast<size_t>(a.size());
  if (py::isinstance<py::array_t<uint8_t>>(a)) {
    im.bit_depth = 8;
    auto c = py::array_t<uint8_t, py::array::c_style>::ensure(a);
    im.u8.assign(c.data(), c.data() + n);
  } else if (py::isinstance<py::array_t<uint16_t>>(a)) {
    im.bit_depth = 16;
    auto c = py::array_t<uint16_t, py::array::c_style>::ensure(a);
    im.u16.assign(c.data(), c.data() + n);
  } else {
    throw UsageError(what + ": expected uint8 or uint16 pixels (the Python layer encodes float images)");
  }
  return im;
}

}  // namespace

void bind_sequence(py::module_& m) {
  py::class_<Sequence, std::shared_ptr<Sequence>>(m, "_Sequence")
      .def_readonly("root", &Sequence::root)
      .def_property_readonly("layout", [](const Sequence& s) { return std::string(sequence_layout_name(s.layout)); })
      .def_readonly("width", &Sequence::width)
      .def_readonly("height", &Sequence::height)
      .def_readonly("event_files", &Sequence::event_files)
      .def_readonly("notes", &Sequence::notes)
      .def_property_readonly("frame_images",
                             [](const Sequence& s) {
                               std::vector<std::string> v;
                               for (const auto& f : s.frames) v.push_back(f.image);
                               return v;
                             })
      .def_property_readonly("timings",
                             [](const Sequence& s) {
                               std::vector<RowTiming> v;
                               for (const auto& f : s.frames) v.push_back(f.timing);
                               return v;
                             })
      .def_property_readonly("ground_truth",
                             [](const Sequence& s) {
                               py::list out;
                               for (const auto& g : s.ground_truth) out.append(py::make_tuple(to_fraction(g.t_us), g.image));
                               return out;
                             })
      .def("meta_gamma", [](const Sequence& s) { return read_meta_gamma(s); })
      .def("event_totals",
           [](const Sequence& s) {
             const EventTotals t = s.event_totals();
             py::dict d;
             d["reads"] = t.reads;
             d["delivered"] = t.delivered;
             d["records"] = t.records;
             d["valid"] = t.valid;
             add_drop_counts(d, t);
             d["empty_files"] = t.empty_files;
             d["summary"] = t.summary();
             return d;
           })
      .def(
          "read_events",
          [](const Sequence& s, int64_t t_begin, int64_t t_end) {
            EventReadReport report;
            EventStream ev = without_gil({s.event_files}, [&] { return s.read_events(t_begin, t_end, &report); });
            return py::make_tuple(from_event_stream(std::move(ev)), report_dict(report));
          },
          py::arg("t_begin_us"), py::arg("t_end_us"));

  m.def("_load_sequence", [](const std::string& path, const py::dict& kw) {
    const SequenceOptions o = guarded({{path}}, [&] { return sequence_options(kw); });
    return without_gil({{path}}, [&] { return std::make_shared<Sequence>(load_sequence(path, o)); });
  });

  m.def(
      "_read_image",
      [](const std::string& path, int width, int height) {
        cv::Mat bgr = without_gil({{path}}, [&] { return read_frame_image(path, width, height); });
        return bgr_mat_to_rgb(bgr);
      },
      py::arg("path"), py::arg("width"), py::arg("height"));

  m.def(
      "_write_sequence",
      [](const std::string& dir, int width, int height, const py::list& frames, const std::vector<RowTiming>& timings,
         const py::list& gt_times, const py::list& gt_images, const I64Array& t, const U16Array& x, const U16Array& y,
         const I8Array& p, const std::string& events_format, const std::string& source_json, bool overwrite) {
        SequenceWriteSpec spec = guarded({}, [&] {
          SequenceWriteSpec s;
          s.width = width;
          s.height = height;
          if (frames.size() != timings.size())
            throw UsageError(dir + ": " + std::to_string(frames.size()) + " frames but " + std::to_string(timings.size()) +
                        " timings (one per frame)");
          for (size_t k = 0; k < frames.size(); ++k)
            s.frames.push_back({sequence_image(frames[k].cast<py::array>(), dir + ": frame " + std::to_string(k)), timings[k]});
          for (size_t g = 0; g < gt_images.size(); ++g)
            s.ground_truth.push_back({sequence_image(gt_images[g].cast<py::array>(), dir + ": ground truth " + std::to_string(g)),
                                      to_rational(gt_times[g], "ground_truth[" + std::to_string(g) + "] time")});
          s.events = to_event_stream(t, x, y, p, width, height);
          s.events_format = events_format;
          s.source_json = source_json;
          return s;
        });
        without_gil({}, [&] {
          write_sequence_folder("Sequence.create.path", dir, overwrite, [&](const std::string& staging) { write_generic_sequence(staging, spec); });
        });
      },
      py::arg("dir"), py::arg("width"), py::arg("height"), py::arg("frames"), py::arg("timings"), py::arg("gt_times"),
      py::arg("gt_images"), py::arg("t"), py::arg("x"), py::arg("y"), py::arg("p"), py::arg("events_format"),
      py::arg("source_json"), py::arg("overwrite"));
}

}  // namespace vkunroll::python

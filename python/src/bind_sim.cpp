// The scene simulator: a synthetic RS + events + ground-truth recording in the generic layout
// (the same as `vkunroll simulate`; settings by the SimulationConfig field names).
#include <fstream>

#include "common.hpp"
#include "output_rule.hpp"
#include "vkunroll/host/sim/recording.hpp"

namespace vkunroll::python {

namespace {

// Sets one SimulationConfig field from a Python value; false when `key` names none.
bool set_setting(sim::SimulationConfig& c, const std::string& key, const py::handle& v) {
  const std::map<std::string, double*> numbers = {
      {"fps", &c.fps}, {"line_delay_us", &c.line_delay_us}, {"exposure_us", &c.exposure_us},
      {"lead_in_us", &c.lead_in_us}, {"speed_scale", &c.speed_scale}, {"flicker_amplitude", &c.flicker_amplitude},
      {"flicker_hz", &c.flicker_hz}, {"gamma", &c.gamma}, {"step_fraction", &c.step_fraction},
      {"dt_min_us", &c.dt_min_us}, {"dt_max_us", &c.dt_max_us}, {"c_on", &c.events.c_on}, {"c_off", &c.events.c_off},
      {"sigma", &c.events.sigma}, {"refractory_us", &c.events.refractory_us}, {"leak_hz", &c.events.leak_hz},
      {"shot_hz", &c.events.shot_hz}, {"cutoff_hz", &c.events.cutoff_hz}, {"eps", &c.events.eps},
      {"full_well_e", &c.frame_noise.full_well_e}, {"read_noise", &c.frame_noise.read_noise}};
  const std::map<std::string, int*> ints = {{"width", &c.width},       {"height", &c.height},   {"frames", &c.frames},
                                            {"gt_per_frame", &c.gt_per_frame}, {"sprites", &c.sprites},
                                            {"supersample", &c.supersample}, {"bit_depth", &c.bit_depth}};
  if (auto it = numbers.find(key); it != numbers.end()) return *it->second = v.cast<double>(), true;
  if (auto it = ints.find(key); it != ints.end()) return *it->second = v.cast<int>(), true;
  if (key == "readout") return c.readout = v.cast<std::string>(), true;
  if (key == "events_format") return c.events_format = v.cast<std::string>(), true;
  if (key == "color") return c.color = v.cast<bool>(), true;
  if (key == "motion") return c.motion = sim::parse_motion_kind(v.cast<std::string>()), true;
  if (key == "texture") return sim::set_texture(c, v.cast<std::string>()), true;
  return false;
}

}  // namespace

void bind_sim(py::module_& m) {
  m.def(
      "_simulate",
      [](const std::string& out, const std::string& preset, uint64_t seed, const py::dict& settings, bool overwrite) {
        sim::SimulationConfig c = guarded({}, [&] {
          sim::SimulationConfig cfg = sim::simulation_preset(preset);
          cfg.seed = seed;
          cfg.events.seed = seed;
          for (auto item : settings) {
            const std::string key = py::str(item.first);
            if (!set_setting(cfg, key, item.second)) throw UsageError("simulate: unknown setting '" + key + "'");
          }
          cfg.validate();
          return cfg;
        });
        const std::string meta = without_gil({}, [&] {
          std::string written;
          // The output is checked (and locked) before the simulation runs.
          write_sequence_folder("simulate.path", out, overwrite,
                                [&](const std::string& staging) { written = sim::write_sequence(c, sim::simulate(c), staging).dump(); });
          return written;
        });
        return meta;
      },
      py::arg("out"), py::arg("preset"), py::arg("seed"), py::arg("settings"), py::arg("overwrite"));
}

}  // namespace vkunroll::python

// The schema of a generic sequence's meta.json, written once: one table of fields (type, unit,
// legal and plausible range) and the cross-field rules as named functions. The loader validates
// the parsed JSON against the table before it reads anything, and docs/reliability.md's
// "meta.json schema" section is generated from the same table (meta_schema_markdown).
#pragma once
#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

struct Sequence;

enum class MetaType { integer, time, number, string, readout, list, object };

struct MetaField {
  const char* path;  // "width", "frames[].t0_us", "source.settings.gamma"
  MetaType type;
  const char* unit;  // "px", "us", "" for none
  bool required;     // within its parent (an element of frames[] needs t0_us)
  double min, max;   // legal range (numbers and times; list: item count); a value outside is an error
  double plausible_min, plausible_max;  // outside: a warning naming the field
  const char* doc;
};

const std::vector<MetaField>& meta_fields();

// A value of meta.json that breaks the schema: "<file>:<field> = <value>: <rule>" (exit 65).
struct MetaSchemaError : DataError {
  MetaSchemaError(const std::string& file, const std::string& name, const std::string& value, const std::string& rule)
      : DataError(file + ":" + name + " = " + value + ": " + rule), field(name) {}
  std::string field;  // "frames[1].t0_us"
};

// Checks every field of the table (type, range, required) and warns on implausible values and on
// fields the schema does not know. Throws MetaSchemaError on the first violation.
std::vector<std::string> validate_meta(const nlohmann::json& meta, const std::string& meta_path);

// Cross-field rules over the loaded sequence; each throws MetaSchemaError naming its rule.
// `t0_field(k)` names where frame k's t0 came from ("meta.json:frames[3].t0_us" or an option).
using FieldName = std::function<std::string(size_t)>;
void rule_readout_within_frame_period(const Sequence& s, const FieldName& t0_field);
void rule_distinct_frame_files(const Sequence& s, const std::string& meta_path);
void rule_ground_truth_inside_recording(const Sequence& s, const std::string& meta_path);
struct ImageHeader {
  int width = 0, height = 0, channels = 0;
};
// A frame or ground-truth image exists, is a regular file and ends whole (image_end_problem); its
// header (size, channels). Error naming the image otherwise (sequence.cpp).
ImageHeader check_sequence_image(const Sequence& s, const std::string& image, const char* what);
// Why the image file at `path` does not end as its format requires, "" when it does (or the format
// has no end marker to check): a PNG's last chunk is IEND, a JPEG's last scan is followed by its EOI
// marker (FF D9). A file cut short (a copy cut in half) fails it, where a decoder would fill the
// missing rows with gray and only warn. Reads at most the file's last 64 KiB.
std::string image_end_problem(const std::string& path);
// Every frame and ground-truth image has the sensor's size and the first frame's channel count.
void rule_images_agree(const Sequence& s, const std::vector<ImageHeader>& frames, const std::vector<ImageHeader>& truth);
// The same rule for one image as it appears (unroll --follow): `field` names it ("frames[3].file"),
// `reference` is the first frame's header (`reference_field` names that frame).
void rule_image_agrees(const Sequence& s, const std::string& field, const std::string& image, const ImageHeader& h,
                       const ImageHeader& reference, const std::string& reference_field);
// Two files are the same image when they are one file: a symlink or a hard link to it (device and
// inode), or the same path. A key per file that is equal exactly then.
std::string image_identity(const std::string& path);

// The schema as the markdown section of docs/reliability.md (between its meta-schema markers).
std::string meta_schema_markdown();

}  // namespace vkunroll

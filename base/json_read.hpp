// The one way vkunroll reads a JSON document (meta.json, a safetensors header, a run's journal, a
// sequence's source record): nlohmann's parser with one rule added, a key repeated inside one
// object is refused, naming the key and the document (nlohmann keeps the last value silently: a
// meta.json with "exposure_us" twice would run with whichever came last).
//
//   const nlohmann::json m = parse_json<nlohmann::json>(stream, path);  // DataError naming `where`
//
// A template over the JSON type, so that base needs no JSON library of its own.
#pragma once
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

// The document parsed from `input` (a string, string_view or istream); DataError naming `where` when
// it is not valid JSON or an object repeats a key (the key and its object's path in the message).
template <class Json, class Input>
Json parse_json(Input&& input, const std::string& where) {
  using Event = typename Json::parse_event_t;
  std::vector<std::set<std::string>> keys;  // the keys seen in each open object
  std::vector<std::string> path;            // the key that opened each open value ("" in arrays and at the top)
  std::string last_key;
  auto check = [&](int /*depth*/, Event event, Json& parsed) {
    switch (event) {
      case Event::object_start:
      case Event::array_start:
        path.push_back(last_key);
        last_key.clear();
        if (event == Event::object_start) keys.emplace_back();
        break;
      case Event::object_end:
        keys.pop_back();
        [[fallthrough]];
      case Event::array_end:
        path.pop_back();
        break;
      case Event::key:
        last_key = parsed.template get<std::string>();
        if (!keys.back().insert(last_key).second) {
          std::string at;
          for (const std::string& p : path)
            if (!p.empty()) at += (at.empty() ? "" : ".") + p;
          throw DataError(where + ": the key \"" + last_key + "\" appears twice in " +
                          (at.empty() ? std::string("the top-level object") : "the object " + at) +
                          " (a repeated key is refused: which value is meant is not known)");
        }
        break;
      default:
        last_key.clear();
        break;
    }
    return true;
  };
  try {
    return Json::parse(std::forward<Input>(input), check);
  } catch (const DataError&) {
    throw;
  } catch (const std::exception& e) {
    throw DataError(where + ": not valid JSON: " + e.what());
  }
}

}  // namespace vkunroll

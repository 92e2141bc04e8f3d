// What `rolamos info` reports, as JSON: for an image, its levels, tiles, codec and georeference;
// for a store, its manifest, the global record and each patch (with any problem found in it,
// so one damaged patch does not hide the others).
#pragma once

#include <string>

#include <nlohmann/json.hpp>

namespace rolamos {

nlohmann::json DescribeImage(const std::string& path);
nlohmann::json DescribeStore(const std::string& dir);
// Human-readable rendering of either description.
std::string FormatDescription(const nlohmann::json& description);

}  // namespace rolamos

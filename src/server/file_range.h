// Whole files over HTTP with range requests (RFC 9110), as GDAL's /vsicurl/ and QGIS read a
// Cloud Optimized GeoTIFF remotely: the header first, then the tiles they need. One range per
// request (GDAL asks one at a time); several ranges, or one that starts past the end, are refused
// with 416 and the reason. The caller names the file; nothing here reads a path from the URL.
#pragma once

#include <string>

namespace httplib {
struct Request;
struct Response;
}  // namespace httplib

namespace rolamos {

void ServeFileRanges(const std::string& path, const std::string& mime, const httplib::Request& req,
                     httplib::Response& res);

}  // namespace rolamos

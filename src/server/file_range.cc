#include "server/file_range.h"

#include <httplib.h>

#include <fcntl.h>
#include <unistd.h>

#include <filesystem>
#include <memory>
#include <vector>

namespace rolamos {

namespace {

// "bytes=A-B", "bytes=A-" or "bytes=-N": false when it is not one such range.
bool ParseOneRange(const std::string& header, long long size, long long* first, long long* last, std::string* why) {
  const std::string unit = "bytes=";
  if (header.compare(0, unit.size(), unit) != 0) {
    *why = "only byte ranges are served (Range: bytes=A-B)";
    return false;
  }
  const std::string spec = header.substr(unit.size());
  if (spec.find(',') != std::string::npos) {
    *why = "one range per request (GDAL and QGIS ask for one at a time)";
    return false;
  }
  const size_t dash = spec.find('-');
  if (dash == std::string::npos) {
    *why = "a range is A-B, A- or -N";
    return false;
  }
  auto number = [](const std::string& s, long long* v) {
    if (s.empty() || s.size() > 18) return false;
    for (char c : s)
      if (c < '0' || c > '9') return false;
    *v = std::stoll(s);
    return true;
  };
  const std::string a = spec.substr(0, dash), b = spec.substr(dash + 1);
  long long x = 0, y = 0;
  if (a.empty()) {  // the last N bytes
    if (!number(b, &y) || y == 0) {
      *why = "a suffix range is -N with N > 0";
      return false;
    }
    *first = std::max(0LL, size - y);
    *last = size - 1;
  } else {
    if (!number(a, &x) || (!b.empty() && (!number(b, &y) || y < x))) {
      *why = "a range is A-B with A <= B";
      return false;
    }
    *first = x;
    *last = b.empty() ? size - 1 : std::min(y, size - 1);
  }
  if (*first >= size) {
    *why = "the range starts at byte " + std::to_string(*first) + ", past the end of the file (" +
           std::to_string(size) + " bytes)";
    return false;
  }
  return true;
}

}  // namespace

void ServeFileRanges(const std::string& path, const std::string& mime, const httplib::Request& req,
                     httplib::Response& res) {
  std::error_code ec;
  const long long size = static_cast<long long>(std::filesystem::file_size(path, ec));
  const auto modified = std::filesystem::last_write_time(path, ec);
  if (ec) {
    res.status = 404;
    res.set_content("the file is not there (not composed or exported yet)\n", "text/plain");
    return;
  }
  const std::string etag = "\"" + std::to_string(modified.time_since_epoch().count()) + "-" + std::to_string(size) + "\"";
  res.set_header("ETag", etag);
  res.set_header("Accept-Ranges", "bytes");
  res.set_header("Cache-Control", "no-cache");
  if (req.has_header("Range")) {
    long long first = 0, last = 0;
    std::string why;
    if (!ParseOneRange(req.get_header_value("Range"), size, &first, &last, &why)) {
      // The reason goes in a header too: the HTTP library cuts the body by the request's ranges.
      res.status = 416;
      res.set_header("Content-Range", "bytes */" + std::to_string(size));
      res.set_header("X-Rolamos-Problem", why);
      res.set_content(why + "\n", "text/plain");
      return;
    }
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    res.status = 500;
    res.set_content("the file cannot be opened\n", "text/plain");
    return;
  }
  auto file = std::shared_ptr<int>(new int(fd), [](int* f) {
    ::close(*f);
    delete f;
  });
  // httplib answers the (one, checked) range: 206 with Content-Range, the provider called for it.
  res.set_content_provider(static_cast<size_t>(size), mime,
                           [file](size_t offset, size_t length, httplib::DataSink& sink) {
                             std::vector<char> buffer(std::min<size_t>(length, 1 << 20));
                             size_t done = 0;
                             while (done < length) {
                               const size_t want = std::min(buffer.size(), length - done);
                               const ssize_t got = ::pread(*file, buffer.data(), want, static_cast<off_t>(offset + done));
                               if (got <= 0) return false;
                               if (!sink.write(buffer.data(), static_cast<size_t>(got))) return false;
                               done += static_cast<size_t>(got);
                             }
                             return true;
                           });
}

}  // namespace rolamos

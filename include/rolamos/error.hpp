// Errors that cross the library boundary. Every message names the file (or option) and what was
// wrong, so a CLI can print it as it is.
#pragma once

#include <stdexcept>
#include <string>

namespace rolamos {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Throws Error("<where>: <what>").
[[noreturn]] void Fail(const std::string& where, const std::string& what);

}  // namespace rolamos

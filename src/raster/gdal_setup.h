// GDAL is set up once per process: drivers registered, errors turned into messages we report
// ourselves (never printed by GDAL), and no side-car .aux.xml files written next to inputs.
#pragma once

#include <string>

namespace rolamos {

void EnsureGdal();
// The last GDAL error message on this thread ("" if none), then cleared.
std::string TakeGdalError();

}  // namespace rolamos

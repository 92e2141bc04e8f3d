#include "raster/gdal_setup.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal.h>

#include <mutex>

namespace rolamos {
namespace {

thread_local std::string g_last_error;

void CPL_STDCALL QuietHandler(CPLErr level, CPLErrorNum, const char* message) {
  if (level >= CE_Failure) g_last_error = message ? message : "";
}

}  // namespace

void EnsureGdal() {
  static std::once_flag once;
  std::call_once(once, [] {
    GDALAllRegister();
    CPLSetConfigOption("GDAL_PAM_ENABLED", "NO");
    CPLSetErrorHandler(QuietHandler);
  });
}

std::string TakeGdalError() {
  std::string e;
  e.swap(g_last_error);
  CPLErrorReset();
  return e;
}

}  // namespace rolamos

#pragma once

namespace rolamos {

// Peak resident set size of this process in MiB (VmHWM), 0 when unknown.
double PeakRssMb();
// Current resident set size in MiB (VmRSS), 0 when unknown.
double CurrentRssMb();

}  // namespace rolamos

#pragma once

#define ROLAMOS_VERSION_STRING "0.1.0"

#pragma once
// The web page's files, compiled into markerd from daemon/src/web/page/
// (web_page.cpp.in, filled in by CMake): markerd serves them without
// reading anything at run time.

#include <string_view>

namespace markerd::daemon::web_page {

extern const std::string_view kIndexHtml;
extern const std::string_view kAppJs;
extern const std::string_view kStyleCss;

}  // namespace markerd::daemon::web_page

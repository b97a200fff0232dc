// Command-line options of `visloc view` (util/option_table.h).
#include "visloc/util/option_table.h"
#include "visloc/viewer/viewer.h"

namespace visloc {

void add_options(OptionTable& t, ViewerOptions& o) {
  t.add("--max-points", o.max_points, "Map points drawn at most, spread over the segments by size").positive();
  t.choice("--frame", o.frame,
           {{"auto", OverviewFrame::kAuto}, {"enu", OverviewFrame::kEnu}, {"segment", OverviewFrame::kSegment}},
           "Frame: 'enu' (georegistered maps: east, north, up), 'segment' (the segments' own shared frame:\n"
           "imported models, known-pose maps; up estimated from the cameras), 'auto' (the report's frame,\n"
           "else enu when every segment is georegistered)");
  t.add("--title", o.title, "Page title [visloc: MAP]");
}

}  // namespace visloc

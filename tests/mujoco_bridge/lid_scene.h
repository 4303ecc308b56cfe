#pragma once

// A soft cube and a lid on a hinge, shared by the coupling tests
// (world_test.cc) and the allocation test.

#include <string>

namespace tetcosim {

// A lid (a 30 x 20 x 2 cm box of 0.3 kg) on a hinge along y at its end, 20
// cm up, and a soft 6 cm cube (3 cells a side, E = 1e5 Pa) to meet it, at
// 10 ms: the hinge's attributes, the cube's placement (pos, vel), more of
// <option>'s attributes, elements before <deformable> and first in it
inline std::string LidScene(const std::string& joint, const std::string& cube,
                            const std::string& option = "", const std::string& before = "",
                            const std::string& first_in_deformable = "") {
  return R"(<mujoco>
  <option timestep="0.01" )" +
         option + R"(/>
  <worldbody>
    <body name="lid" pos="-0.15 0 0.2">
      <joint name="hinge" type="hinge" axis="0 1 0" )" +
         joint + R"(/>
      <geom name="lid" type="box" pos="0.15 0 0" size="0.15 0.1 0.01" mass="0.3"/>
    </body>
  </worldbody>
  )" + before +
         R"(
  <deformable>)" +
         first_in_deformable + R"(
    <rigidtet body="lid" geom="lid" resolution="4"/>
    <tetbody name="cube" shape="box" size="0.03 0.03 0.03" resolution="3" )" +
         cube + R"(
             density="1000" young="1e5"/>
  </deformable>
</mujoco>)";
}

}  // namespace tetcosim

#pragma once

// Scenes of rigid bodies on a stiff pinned deformable slab, shared by the
// coupling tests (world_test.cc) and the substep scenarios.

#include <string>

namespace tetcosim {

// A scene of `bodies` over a stiff slab (E = 1e7 Pa, 4 cm thick, its top at
// z = 0, its bottom pinned to a static body) of the given half-sizes and
// cells in x and y, with `deformable` (proxies, settings) beside it;
// stick: static friction (<contact stick>).
inline std::string OnAStiffSlab(const std::string& bodies, const std::string& deformable,
                                const std::string& half_size, const std::string& cells,
                                bool stick = true) {
  return R"(<mujoco>
  <option timestep="0.001" gravity="0 0 -9.81"/>
  <worldbody>
    <body name="anchor"/>)" +
         bodies + R"(
  </worldbody>
  <deformable>
    <contact friction="0.5" stick=")" +
         (stick ? std::string("true") : std::string("false")) + R"("/>)" + deformable + R"(
    <tetbody name="slab" shape="box" size=")" +
         half_size + R"( 0.02" resolution=")" + cells + R"( 2" pos="0 0 -0.02" young="1e7"/>
    <attach tetbody="slab" body="anchor" box="-1 -1 -1 1 1 -0.039"/>
  </deformable>
</mujoco>)";
}

// A light two-link arm (hinges about y at the shoulder and the elbow, 50 g
// and 30 g) whose hand, a box proxy 2 cm off the lower link's axis, falls
// 2 cm onto the slab; solved to 1e-12 with the given substeps (and static
// friction or the smooth law alone).
inline std::string ArmOnAStiffSlab(int substeps, bool stick = true) {
  return OnAStiffSlab(R"(
    <body name="upper" pos="-0.2 0 0.06">
      <joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.05" contype="0"
            conaffinity="0"/>
      <body name="lower" pos="0.1 0 0">
        <joint type="hinge" axis="0 1 0"/>
        <geom name="hand" type="box" pos="0.05 0 -0.02" size="0.05 0.02 0.02" mass="0.03"
              contype="0" conaffinity="0"/>
      </body>
    </body>)",
                      R"(
    <solver tolerance="1e-12" substeps=")" +
                          std::to_string(substeps) + R"("/>
    <rigidtet body="lower" geom="hand" resolution="3"/>)",
                      "0.15 0.1", "15 10", stick);
}

}  // namespace tetcosim

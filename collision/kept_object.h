#pragma once

// What the penetration solver keeps of a large body that does not move
// (CollisionObject::fixed) or moves rigidly (CollisionObject::frame) from
// one solve to the next, so that such a body costs a solve about what its
// contacts cost (docs/collision.md, "Fixed objects" and "Framed objects").
// Internal to collision/.

#include <Eigen/Core>
#include <vector>

#include "collision/box_tree.h"
#include "collision/collision_object.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

// What the solver keeps of a fixed object (CollisionObject::fixed) or one
// moving with a frame (CollisionObject::frame, "framed") between solves,
// and what a solve found in it: its box, a tree over its chunks' boxes (a
// chunk's box: that of its tets' corners), per chunk its surface faces
// (the faces of its tets, ascending), and a tree over its faces. A framed
// object's boxes are in its body frame, grown by `pad`.
struct KeptObject {
  const TetMesh* mesh = nullptr;  // the object seen last (null: none)
  const Positions* positions = nullptr;
  bool framed = false;
  std::vector<int> sample_vertex;       // compared every solve
  std::vector<Eigen::Vector3d> sample;  // their positions (body frame if framed) when kept
  bool built = false;                   // what follows is of those positions
  Eigen::Vector3d lo, hi;               // box, before Inflate (not framed)
  bool finite = true;                   // every position is finite
  // framed: this solve's frame; the largest body-frame coordinate (in
  // magnitude); the growth of the kept boxes, which covers the rounding of
  // positions taken into the body frame
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  double body_scale = 0.0, pad = 0.0;
  // a world point in the frame of the kept boxes
  Eigen::Vector3d ToBody(const Eigen::Vector3d& p) const {
    return framed ? Eigen::Vector3d(rotation.transpose() * (p - translation)) : p;
  }
  std::vector<Eigen::Vector3d> run_lo, run_hi;  // per chunk
  BoxTree runs;                                 // over the chunks' boxes
  std::vector<int> run_face_offset, run_faces;  // per chunk its surface faces
  // closest features (the closest method, fallback values): a box tree
  // over all its surface faces (item f: face f), their boxes as
  // MakeTriangle's
  BoxTree faces;
  std::vector<Eigen::Vector3d> face_lo, face_hi;
  std::vector<int> loose_vertices;  // in no tet (TetMeshOptions::drop_unreferenced off)
  bool active = false;              // this solve: fixed or framed, and kept
  std::vector<int> searched;        // this solve: chunks whose box meets the search box
  // this solve: the vertices of those chunks (and loose ones) that got an
  // outcode, with repeats, and those in the search box, ascending; the
  // others' outcodes are kBeyondEverySide, all set when its first vertex
  // was at outcode_offset among the objects' (-1: not set)
  std::vector<int> classified, hashed;
  int outcode_offset = -1;

  // Whether a fixed or framed object can use what is kept of it this solve:
  // it can unless some of its sampled vertices moved since they were kept
  // (then it is solved without, and kept again once it stays still, or
  // rigid) or its frame is not a rotation; keeps it if it is not kept yet.
  // (object: CollisionObject::fixed, or with a frame.)
  bool Keep(const CollisionObject& object);
};

}  // namespace tetcosim

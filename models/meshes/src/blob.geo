// Something irregular: a sphere fused with a tilted cylinder and a box,
// meshed with a size field that varies across the body.
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.04};
Cylinder(2) = {0, 0, 0, 0.05, 0.03, 0.04, 0.018};
Box(3) = {-0.05, -0.02, -0.02, 0.04, 0.04, 0.03};
BooleanUnion(4) = {Volume{1}; Delete;}{Volume{2}; Volume{3}; Delete;};
Field[1] = MathEval;
Field[1].F = "0.006 + 0.1 * sqrt(x*x + y*y + z*z)";
Background Field = 1;
Mesh.CharacteristicLengthExtendFromBoundary = 0;
Mesh.CharacteristicLengthFromPoints = 0;

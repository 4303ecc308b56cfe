// An L-shaped block (0.1 x 0.1 x 0.04 m with a 0.05 x 0.05 notch): concave,
// with sharp edges and corners.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 0.1, 0.1, 0.04};
Box(2) = {0.05, 0.05, -0.01, 0.06, 0.06, 0.06};
BooleanDifference(3) = {Volume{1}; Delete;}{Volume{2}; Delete;};
Physical Volume("body", 7) = {3};
Mesh.CharacteristicLengthMin = 0.012;
Mesh.CharacteristicLengthMax = 0.012;

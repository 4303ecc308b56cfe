// A coarse sphere (radius 0.05 m) for reader tests.
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.05};
Mesh.CharacteristicLengthMin = 0.03;
Mesh.CharacteristicLengthMax = 0.03;

// A sphere of radius 0.05 m for tetcosim (gmsh -3).
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 0.05};
Mesh.CharacteristicLengthMin = 0.012;
Mesh.CharacteristicLengthMax = 0.012;

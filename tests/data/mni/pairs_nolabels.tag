MNI Tag Point File
Volumes = 2;
% Volume 1 produced by VTK
% Volume 2 produced by VTK

Points =
 10.5 -20.25 30.125 11.25 -19.5 31
 -40.0625 50.5 -60.75 -39.5 51.125 -59.875
 70.875 80.3125 -90.5 71.625 81 -89.75
 -1.5 -2.25 -3.125 -0.75 -1.5 -2.375;

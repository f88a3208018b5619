from runout.cli import main

main()
